"""``hingelab trial`` on the MuJoCo stand-in: the simulation's verdict, operator mode, what a trial records, a cut-off
trial."""

from __future__ import annotations

import sys

import numpy as np
import pandas as pd
import pytest

from hingelab.episodes import create_dataset, read_episode
from hingelab.episodes import schemas as S


@pytest.fixture(scope="module")
def stand_in():
    from hingelab.robot.controller import CheckpointHighLevel, HierarchicalController
    from hingelab.robot.stand_in import StandInRobot

    robot = StandInRobot("sphere", 0.02, max_steps=200)
    controller = HierarchicalController(CheckpointHighLevel("assets/checkpoints/high_level.zip"))
    yield robot, controller
    robot.close()


def _dataset(tmp_path, name):
    root = tmp_path / name
    create_dataset(root, name=name, source="stand_in", seed=0, config={})
    return root


@pytest.fixture(scope="module")
def trial_episode(stand_in, tmp_path_factory):
    from hingelab.robot.trial import TrialConfig, run_trials

    robot, controller = stand_in
    root = _dataset(tmp_path_factory.mktemp("trial"), "sim")
    rows = run_trials(robot, controller, root, TrialConfig(trials=1, max_steps=12, depth_every=4), progress=False)
    (path,) = sorted((root / "episodes").glob("*.mcap"))
    return rows, path


def test_a_trial_records_camera_cloud_joints_and_outcome(trial_episode):
    from hingelab.episodes.camera_topics import read_camera

    rows, path = trial_episode
    assert list(rows.columns[:4]) == ["trial", "seed", "success", "first_attempt_success"]
    episode = read_episode(path)
    meta = episode.metadata
    assert meta["source"] == "stand_in" and meta["outcome_by"] == "simulation"
    assert meta["success"] == bool(rows.success[0]) and meta["attempt"] == int(rows.attempts[0])
    assert episode.points.shape == (12, 256, 3)
    for topic in (S.TOPIC_TOOL_POSE, S.TOPIC_JOINTS, S.TOPIC_ARM_JOINTS, S.TOPIC_LATENT, S.TOPIC_ACTION,
                  S.TOPIC_OBJECT, S.TOPIC_TARGET, S.TOPIC_PRIVILEGED):
        assert len(episode[topic]["log_time_ns"]) == 12, topic
    assert episode[S.TOPIC_ARM_JOINTS]["position"].shape == (12, 6)
    camera = read_camera(path)
    assert camera.depth.shape == (3, 576, 640)  # steps 0, 4, 8
    assert camera.intrinsics.fx == pytest.approx(417.03, abs=0.01) and camera.rotation.shape == (3, 3, 3)
    valid = camera.depth[0] > 0
    assert valid.mean() > 0.3 and 0.5 < np.median(camera.depth[0][valid]) < 3.0
    # the recorded tool cloud lies in the crop box around the tool, in hand_base
    assert np.all(np.abs(episode.points).max(axis=(0, 1)) < 0.2)
    # /scene (schema 6): every step shows the object, target, tips and the stand-in's platform for Foxglove
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        scenes = [SceneUpdate.FromString(m.data) for _, _, m in make_reader(f).iter_messages(topics=[S.TOPIC_SCENE])]
    assert len(scenes) == 12
    assert all(sorted(e.id for e in u.entities) == sorted(S.SCENE_ENTITIES) for u in scenes)
    size = next(e for e in scenes[0].entities if e.id == S.SCENE_OBJECT).spheres[0].size
    assert [size.x, size.y, size.z] == pytest.approx([float(meta["object_size"])] * 3)


def test_the_view_shows_the_depth_image_and_the_camera_frustum(trial_episode, tmp_path):
    from hingelab.viewers import entities as E
    from hingelab.viewers.view import view
    from test_view_episode import rrd_tables

    _, path = trial_episode
    rrd = tmp_path / "trial.rrd"
    view(path, save=rrd, progress=False)
    tables = rrd_tables(rrd)  # entity paths as Rerun stores them: with a leading slash
    assert "/" + E.CAMERA in tables and "/" + E.CAMERA_DEPTH in tables
    names = " ".join(tables["/" + E.CAMERA].column_names)
    assert "Pinhole" in names and "Transform3D" in names
    depth = tables["/" + E.CAMERA_DEPTH]
    assert depth.filter(depth.column("step").is_valid()).num_rows == 3  # the frames of steps 0, 4, 8


def test_operator_mode_asks_each_attempt_and_records_the_answers(tmp_path, stand_in):
    from hingelab.robot.trial import TrialConfig, run_trials

    robot, controller = stand_in
    answers = iter(["maybe", "s", "a"])
    asked, said = [], []

    def read(question):
        asked.append(question)
        return next(answers)

    root = _dataset(tmp_path, "operator")
    rows = run_trials(robot, controller, root, TrialConfig(trials=2, max_steps=6, operator=True),
                      read=read, write=said.append, progress=False)
    # trial 1: an answer that is none of s/f/a is asked again, then success; trial 2: aborted
    assert len(asked) == 3 and "attempt 1" in asked[0] and any("answer s" in s for s in said)
    assert rows.success.tolist() == [True, False] and rows.failure_reason.tolist() == ["", "aborted"]
    metas = sorted((read_episode(p).metadata for p in (root / "episodes").glob("*.mcap")), key=lambda m: m["trial"])
    assert [m["outcome_by"] for m in metas] == ["operator", "operator"]
    assert metas[0]["first_attempt_success"] is True and metas[1]["failure_reason"] == "aborted"


def test_operator_mode_through_standard_input(tmp_path, capsys, monkeypatch):
    """The command reads the operator's answer from standard input (``input``), here a StringIO: in this process
    rather than a started ``hingelab trial`` (the same parser and command; a process start costs seconds)."""
    import io

    from hingelab.cli.main import main

    out = tmp_path / "trial"
    monkeypatch.setattr(sys, "stdin", io.StringIO("f\n"))
    capsys.readouterr()
    assert main(["trial", "--trials", "1", "--max-steps", "5", "--operator", "--out", str(out)]) == 0
    stdout = capsys.readouterr().out
    assert "attempt 1: [s]uccess, [f]ailure or [a]bort?" in stdout
    trials = pd.read_csv(out / "trials.csv")
    assert not trials.success[0] and trials.attempts[0] == 1
    assert "judged by the operator" in stdout and (out / "table.csv").is_file()


def test_a_trial_cut_off_leaves_a_recoverable_file(tmp_path, stand_in):
    from hingelab.episodes.recover import recover_episode
    from hingelab.robot.trial import FLUSH_EVERY, TrialConfig, run_trials

    robot, controller = stand_in

    class Interrupted:  # the stand-in, until Ctrl-C comes in the middle of the trial
        def __init__(self, robot, after):
            self.robot, self.after, self.steps = robot, after, 0
            self.source, self.arm_joint_names, self.hand_joint_names = (robot.source, robot.arm_joint_names,
                                                                        robot.hand_joint_names)
            self.sim = robot.sim

        def start_trial(self, seed):
            return self.robot.start_trial(seed)

        def command(self, velocity, targets):
            self.steps += 1
            if self.steps > self.after:
                raise KeyboardInterrupt
            return self.robot.command(velocity, targets)

        def verdict(self):
            return self.robot.verdict()

    root = _dataset(tmp_path, "cut")
    with pytest.raises(KeyboardInterrupt):
        run_trials(Interrupted(robot, FLUSH_EVERY + 5), controller, root, TrialConfig(trials=1), progress=False)
    (partial,) = list((root / "episodes").glob("*.partial"))
    assert not list((root / "episodes").glob("*.mcap"))
    salvaged = tmp_path / "salvaged.mcap"
    recover_episode(partial, salvaged)
    assert len(read_episode(salvaged).points) >= FLUSH_EVERY

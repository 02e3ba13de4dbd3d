"""The camera's object estimate where the camera path runs: ToolPick-v0 and ``eval high`` with ``object_perception``,
and ``hingelab trial`` on the stand-in: what the episode records, the estimate's bias toward the camera, a frame where
the tool hides the object, and an episode that never estimates it."""

from __future__ import annotations

import numpy as np
import pytest

from hingelab.episodes import create_dataset, read_episode
from hingelab.episodes import schemas as S
from hingelab.rollouts import high_level as H
from hingelab.sim.rig_camera import camera_pose_world

SIZE = 0.02


def _dataset(tmp_path, name, source="high_level_evaluation"):
    root = tmp_path / name
    create_dataset(root, name=name, source=source, seed=0, config={})
    return root


def _eval_env(root, max_steps=6):
    env = H.make_eval_env("sphere", SIZE, "privileged", record_dir=root, max_episode_steps=max_steps,
                          perception="camera", object_perception="centroid")
    env.unwrapped.perception.source.extrinsic_error = (0.0, 0.0)  # the segmentation's bias alone, no calibration
    return env


def _hide_object(env, by_tool: bool):
    """From now on the object's pixels are the tool's (``by_tool``) or nothing's (out of view)."""
    camera = env.unwrapped.object_camera
    observe = camera.observe
    tool_geom = int(env.unwrapped.perception.camera.renderer._tool_geoms[0]) if by_tool else -1

    def hidden(clouds, rotation, position):
        covered = np.isin(clouds.geoms, camera._object_geoms)
        clouds.geoms = np.where(covered, tool_geom, clouds.geoms)
        if by_tool:
            clouds.frame.tool_mask = clouds.frame.tool_mask | covered
        return observe(clouds, rotation, position)

    camera.observe = hidden


def test_eval_high_with_the_centroid_records_the_estimate_biased_toward_the_camera(tmp_path):
    root = _dataset(tmp_path, "centroid")
    env = _eval_env(root)
    pick = env.unwrapped
    along, across, errors = [], [], []
    try:
        env.reset(seed=5)
        done = False
        while not done:
            _, _, terminated, truncated, info = env.step(np.zeros(5))
            done = terminated or truncated
            truth, estimate = pick.observed_object_centre(), pick.object_camera.estimate
            ray = truth - camera_pose_world(pick.sim.model, pick.sim.data)[1]
            ray /= np.linalg.norm(ray)
            along.append(-(estimate - truth) @ ray)  # positive: toward the camera
            across.append(np.linalg.norm((estimate - truth) - ((estimate - truth) @ ray) * ray))
            errors.append(np.linalg.norm(estimate - truth))
    finally:
        env.close()
    assert info["failure_reason"] == "timeout" and info["object_perception_flag"] is None
    # the paper's centroid sees the near side: toward the camera by a few mm, at most half the object's depth
    assert 0.001 < np.median(along) < SIZE / 2
    assert np.median(across) < 0.003
    (path,) = sorted((root / "episodes").glob("*.mcap"))
    episode = read_episode(path)
    assert episode.metadata["object_perception"] == "centroid"
    assert episode.metadata["schema_version"] == S.SCHEMA_VERSION
    record = episode[S.TOPIC_OBJECT_ESTIMATE]
    assert record["position"].shape == (7, 3) and record["true_position"].shape == (7, 3)  # reset + 6 steps
    assert record["fresh"].all() and (record["n_points"] > 20).all()
    # recorded in hand_base: the same distances as in the world
    np.testing.assert_allclose(np.linalg.norm(record["position"] - record["true_position"], axis=1)[1:], errors,
                               atol=1e-9)
    assert len(episode[S.TOPIC_OBJECT_POINTS]["log_time_ns"]) == 7


def test_a_frame_where_the_tool_hides_the_object_keeps_the_last_estimate(tmp_path):
    env = _eval_env(_dataset(tmp_path, "hidden"))
    pick = env.unwrapped
    try:
        env.reset(seed=6)
        env.step(np.zeros(5))
        last = pick.object_camera.estimate.copy()
        _hide_object(env, by_tool=True)
        _, _, terminated, truncated, info = env.step(np.zeros(5))
    finally:
        env.close()
    assert info["object_perception_flag"] == "hidden_by_tool" and not (terminated or truncated)
    np.testing.assert_array_equal(pick.object_camera.estimate, last)
    assert not pick.object_camera.fresh and pick.last_record["object_estimate"]["flag"] == "hidden_by_tool"


def test_an_episode_that_never_estimates_the_object_ends_cleanly_and_is_written(tmp_path):
    root = _dataset(tmp_path, "unseen")
    env = _eval_env(root)
    try:
        _hide_object(env, by_tool=False)
        obs, _ = env.reset(seed=7)
        assert np.isfinite(obs).all()  # the platform's middle stands in for the centre until there is one
        _, _, terminated, truncated, info = env.step(np.zeros(5))
    finally:
        env.close()
    assert truncated and not terminated
    assert info["failure_reason"] == "no_object_estimate" and info["object_perception_flag"] == "no_object_pixels"
    (path,) = sorted((root / "episodes").glob("*.mcap"))
    episode = read_episode(path)
    assert episode.length == 1 and episode.metadata["failure_reason"] == "no_object_estimate"
    assert not episode[S.TOPIC_OBJECT_ESTIMATE]["fresh"].any()


def test_an_object_estimator_needs_the_camera_and_a_known_name(capsys):
    from hingelab.cli.main import main

    assert main(["eval", "high", "--baseline", "random", "--object-perception", "centroid", "--out", "/nonexistent/x",
                 "--no-progress"]) == 1
    assert main(["trial", "--object-perception", "median", "--out", "/nonexistent/y", "--no-progress"]) == 1
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 2
    assert "needs perception 'camera'" in errors[0] and "object perception 'median' is unknown" in errors[1]


@pytest.fixture(scope="module")
def centroid_stand_in():
    from hingelab.robot.controller import CheckpointHighLevel, HierarchicalController
    from hingelab.robot.stand_in import StandInRobot

    robot = StandInRobot("sphere", SIZE, max_steps=200, object_perception="centroid")
    controller = HierarchicalController(CheckpointHighLevel("assets/checkpoints/high_level.zip"))
    yield robot, controller
    robot.close()


def test_a_stand_in_trial_records_the_estimator_the_estimate_and_the_truth(centroid_stand_in, tmp_path):
    from hingelab.robot.trial import TrialConfig, run_trials

    robot, controller = centroid_stand_in
    root = _dataset(tmp_path, "trial", source="stand_in")
    run_trials(robot, controller, root, TrialConfig(trials=1, max_steps=4, object_perception="centroid"),
               progress=False)
    (path,) = sorted((root / "episodes").glob("*.mcap"))
    episode = read_episode(path)
    assert episode.metadata["object_perception"] == "centroid"
    record = episode[S.TOPIC_OBJECT_ESTIMATE]
    assert record["position"].shape == (4, 3) and record["fresh"].all()
    error = np.linalg.norm(record["position"] - record["true_position"], axis=1)
    assert (error > 0.0005).all() and (error < 0.03).all()  # the bias, the mask errors and the calibration error
    # the controller was given the estimate: the recorded object position is it
    np.testing.assert_allclose(episode[S.TOPIC_OBJECT]["position"], record["position"], atol=1e-9)


def test_a_trial_without_an_object_estimate_ends_cleanly_and_is_written(centroid_stand_in, tmp_path):
    from hingelab.robot.trial import TrialConfig, run_trials

    robot, controller = centroid_stand_in
    root = _dataset(tmp_path, "unseen-trial", source="stand_in")
    camera = robot.pick.object_camera
    observe = camera.observe

    def out_of_view(clouds, rotation, position):
        clouds.geoms = np.where(np.isin(clouds.geoms, camera._object_geoms), -1, clouds.geoms)
        return observe(clouds, rotation, position)

    camera.observe = out_of_view
    messages = []
    try:
        rows = run_trials(robot, controller, root, TrialConfig(trials=1, max_steps=4, object_perception="centroid"),
                          write=messages.append, progress=False)
    finally:
        camera.observe = observe
    assert rows.failure_reason[0] == "no_object_estimate" and "not estimated the object" in messages[0]
    (path,) = sorted((root / "episodes").glob("*.mcap"))
    episode = read_episode(path)
    assert episode.metadata["failure_reason"] == "no_object_estimate"
    assert np.isnan(episode[S.TOPIC_OBJECT_ESTIMATE]["position"]).all()

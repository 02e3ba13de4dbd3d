"""ToolPick-v0's ``tool_position``: the tracked tool position as observed (the paper's, with the clouds' per-episode
calibration error) or anchored (the nominal in-hand position plus the tracked change), and ``eval high
--tool-position``."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import hingelab.envs  # noqa: F401  (registers the envs)
from hingelab.cli.main import main
from hingelab.episodes import EpisodeFile
from hingelab.episodes.dataset import Dataset
from hingelab.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]


def _episode(tool_position: str, steps: int = 12) -> tuple[np.ndarray, np.ndarray]:
    env = gym.make("hingelab/ToolPick-v0", object="tetrahedron", size=0.015, low_level="privileged",
                   tool_position=tool_position)
    try:
        observation, _ = env.reset(seed=11)
        rows = [observation]
        for k in range(steps):
            action = np.array([0.0, 0.0, 0.3 * np.sin(k), 0.2, -0.3])  # the hand moves: the tracked tool with it
            rows.append(env.step(action)[0])
        return np.asarray(rows), np.asarray(env.unwrapped.perception.tool_state.prior[1], float)
    finally:
        env.close()


def test_anchored_is_the_observed_position_moved_to_the_nominal_by_one_constant_and_nothing_else_changes():
    observed, nominal = _episode("observed")
    anchored, _ = _episode("anchored")
    np.testing.assert_array_equal(anchored[:, 3:], observed[:, 3:])  # the same episode: only the position differs
    shift = anchored[:, :3] - observed[:, :3]
    np.testing.assert_allclose(shift, np.broadcast_to(shift[0], shift.shape), atol=1e-12)  # one constant
    np.testing.assert_allclose(anchored[0, :3], nominal, atol=1e-12)  # the first frame is the nominal position
    assert np.ptp(observed[:, :3], axis=0).max() > 1e-4  # and the tracked position did move
    # the paper's clouds carry up to 2 cm of calibration error per axis: the constant is that error, not zero
    assert np.abs(shift[0]).max() > 1e-3


def test_a_bad_tool_position_is_a_one_line_error():
    with pytest.raises(ConfigError, match="tool_position 'true' is unknown; choose one of observed, anchored"):
        gym.make("hingelab/ToolPick-v0", tool_position="true")


def test_eval_high_records_the_anchored_tool_position(tmp_path, capsys):
    out = tmp_path / "anchored"
    assert main(["eval", "high", "--tool-position", "anchored", "--object", "sphere", "--episodes", "2",
                 "--out", str(out), "--no-progress"]) == 0
    assert "(anchored tool position)" in capsys.readouterr().out
    dataset = Dataset(out)
    assert dataset.card.config["tool_position"] == "anchored"
    for name in dataset.index["file"]:
        with EpisodeFile(out / "episodes" / name) as episode_file:
            assert episode_file.metadata()["tool_position"] == "anchored"
    with pytest.raises(SystemExit):
        main(["eval", "high", "--tool-position", "true", "--out", str(tmp_path / "bad")])


def test_a_stand_in_trial_observes_the_anchored_position_and_records_it(tmp_path):
    from hingelab.robot.trial import TrialConfig, run_trial_session

    config = TrialConfig(object="sphere", size=0.02, trials=1, max_steps=4, depth_every=2, tool_position="anchored")
    session = run_trial_session("sim", config, tmp_path / "t", progress=False)
    dataset = Dataset(tmp_path / "t")
    assert dataset.card.config["tool_position"] == "anchored"
    name = dataset.index["file"].iloc[0]
    with EpisodeFile(tmp_path / "t" / "episodes" / name) as episode_file:
        assert episode_file.metadata()["tool_position"] == "anchored"
    assert len(session.rows) == 1
    with pytest.raises(ConfigError, match="tool position 'x' is unknown"):
        TrialConfig(tool_position="x")


def test_the_controller_observes_the_nominal_position_first_and_then_the_tracked_change():
    from hingelab.robot.controller import HierarchicalController
    from hingelab.robot.stand_in import StandInRobot

    class Still:  # a high level that asks for the same action whatever it observes: both runs move alike
        label, low_level, observe_extent = "still", "policy", False

        def reset(self, seed):
            pass

        def act(self, observation):
            return np.array([0.0, 0.0, 0.2, 0.1, -0.2])

    robot = StandInRobot("sphere", 0.02, max_steps=6)
    try:
        high = Still()
        runs = {}
        for mode in ("observed", "anchored"):
            controller = HierarchicalController(high, tool_position=mode)
            readings = robot.start_trial(5)
            controller.reset(readings, 5)
            rows = []
            for _ in range(4):
                step = controller.act(readings)
                rows.append(step.observation)
                readings = robot.command(step.hand_velocity, step.hand_changes)
            runs[mode] = np.asarray(rows)
        nominal = np.asarray(controller.tool_state.prior[1], float)
        np.testing.assert_allclose(runs["anchored"][0, :3], nominal, atol=1e-9)
        np.testing.assert_allclose(runs["anchored"][:, :3] - runs["anchored"][0, :3],
                                   runs["observed"][:, :3] - runs["observed"][0, :3], atol=1e-9)
        np.testing.assert_array_equal(runs["anchored"][:, 3:], runs["observed"][:, 3:])
        assert np.ptp(runs["observed"][:, :3], axis=0).max() > 1e-4  # the tracked tool did move
    finally:
        robot.close()
    with pytest.raises(ConfigError, match="tool position 'x' is unknown"):
        HierarchicalController(high, tool_position="x")


def _rows(arms: dict[str, list[bool]]) -> list[dict]:
    return [{"arm": arm, "seed": i, "first_attempt_success": ok, "success": ok, "failure_reason": "" if ok else "slip"}
            for arm, picks in arms.items() for i, ok in enumerate(picks)]


def test_the_tool_position_verdict_counts_paired_episodes_and_can_say_the_error_costs_nothing():
    from hingelab.rollouts import tool_position_diagnostic as D

    costly = D.summarize(_rows({D.OBSERVED: [1, 0, 0, 1, 1], D.NO_ERROR: [1, 1, 1, 0, 1], D.ANCHORED: [1, 1, 0, 1, 1]}))
    assert [s["first_attempt"] for s in costly] == [3, 4, 4]
    assert (costly[1]["won_vs_observed"], costly[1]["lost_vs_observed"]) == (2, 1)
    text = D.verdict(costly)
    assert text.startswith("The calibration error costs 1 of 5") and "wins back 1 net (1 won, 0 lost)" in text
    free = D.summarize(_rows({D.OBSERVED: [1, 0, 1], D.NO_ERROR: [1, 0, 1], D.ANCHORED: [1, 1, 1]}))
    assert D.verdict(free).startswith("The calibration error costs no first-attempt picks here (net +0 of 3")
    assert "slip 1" in free[0]["misses"]
    clean = D.summarize(_rows({D.OBSERVED: [1, 1], D.NO_ERROR: [1, 1], D.ANCHORED: [1, 1]}))
    assert D.verdict(clean).startswith("The observed arm picks all 2 at the first attempt")


def test_diagnose_tool_position_runs_the_three_arms_on_the_same_seeds(tmp_path, capsys, monkeypatch):
    from hingelab.rollouts import tool_position_diagnostic as D

    drawn = []
    make = D._env

    def watched(model, low_level, object, size, arm):  # each arm's env, and the error its clouds draw
        env = make(model, low_level, object, size, arm)
        reset = env.reset

        def reset_and_look(**kwargs):
            result = reset(**kwargs)
            drawn.append((arm, float(np.abs(env.unwrapped.perception.synthesizer.perturbation[1]).max())))
            return result
        env.reset = reset_and_look
        return env
    monkeypatch.setattr(D, "_env", watched)
    out = tmp_path / "tp"
    assert main(["diagnose", "tool-position", str(REPO / D.OBSERVED_CLONE), "--object", "sphere", "--size", "0.02",
                 "--episodes", "2", "--out", str(out), "--allow-dirty", "--no-progress"]) == 0
    assert "wrote" in capsys.readouterr().out
    import pandas as pd
    episodes = pd.read_csv(out / "episodes.csv")
    assert list(episodes["arm"]) == [a for a in D.ARMS for _ in range(2)]
    assert len(set(episodes.groupby("arm")["seed"].apply(tuple))) == 1  # the same resets in every arm
    errors = {arm: max(e for a, e in drawn if a == arm) for arm in D.ARMS}
    assert errors[D.NO_ERROR] == 0.0 and errors[D.OBSERVED] > 1e-3 and errors[D.ANCHORED] > 1e-3
    assert (out / "tool_position.md").read_text().count("| ") >= 3


def test_a_policy_trained_on_another_tool_position_is_named_with_its_form(tmp_path, capsys):
    relative = REPO / "analysis/high-level/dagger-runs/dagger_relative_fit_s0/model.zip"  # trained on "relative"
    assert main(["diagnose", "tool-position", str(relative), "--episodes", "1", "--out", str(tmp_path / "tp"),
                 "--allow-dirty", "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "was trained on the relative tool position" in err and str(relative) in err


def test_the_observation_form_is_read_from_the_checkpoint():
    from hingelab.policies.high_level import SHIPPED_HIGH_LEVEL, observation_form
    from hingelab.policies.loading import load_policy
    from hingelab.rollouts.tool_position_diagnostic import OBSERVED_CLONE

    assert observation_form(load_policy(SHIPPED_HIGH_LEVEL, level="high")) == {"observe_extent": True,
                                                                                "tool_position": "relative"}
    assert observation_form(load_policy(REPO / OBSERVED_CLONE, level="high")) == {"observe_extent": True,
                                                                                   "tool_position": "observed"}

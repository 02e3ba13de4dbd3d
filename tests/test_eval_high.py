"""`hingelab eval high`: a high-level checkpoint or a baseline on ToolPick-v0 into an evaluation dataset."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hingelab.cli.main import main
from hingelab.episodes import EpisodeFile
from hingelab.episodes.dataset import Dataset

LOW_LEVEL_ZIP = str(Path(__file__).resolve().parents[1] / "assets" / "checkpoints" / "low_level.zip")


def _eval(out, *args) -> int:
    return main(["eval", "high", *args, "--episodes", "2", "--out", str(out), "--no-progress"])


def _true(value) -> bool:
    """A metadata flag (a bool, or its text in keys the schema does not type)."""
    return value is True or str(value).lower() == "true"


def _check_dataset(out) -> pd.DataFrame:
    """The dataset's episodes carry the outcome fields, and the table counts what the dataset records."""
    index = Dataset(out).index
    assert len(index) == 2 and set(index["source"]) == {"high_level_evaluation"}
    metas = []
    for name in index["file"]:
        with EpisodeFile(out / "episodes" / name) as episode_file:
            metas.append(episode_file.metadata())
    for meta in metas:
        assert {"success", "first_attempt_success", "attempt"} <= set(meta)
        assert _true(meta["success"]) or meta["failure_reason"] in (
            "divergence", "tool_drop", "slip", "table_collision", "missed_grasp", "timeout")
    table = pd.read_csv(out / "table.csv").iloc[0]
    assert table["episodes"] == len(index)
    assert table["successes"] == int(index["success"].sum())
    assert table["first_attempt_successes"] == sum(_true(m["first_attempt_success"]) for m in metas)
    failures = index.loc[~index["success"].astype(bool), "failure_reason"].value_counts()
    for reason, count in failures.items():
        assert table[f"failures_{reason}"] == count
    episodes = pd.read_csv(out / "episodes.csv")
    assert sorted(episodes["seed"]) == sorted(index["seed"].astype(int))
    assert "Wilson" in (out / "report.md").read_text()
    return episodes


@pytest.mark.parametrize("baseline", ["heuristic", "scripted", "scripted-observed", "scripted-feedback", "random"])
def test_baselines_write_a_dataset_and_a_table_that_counts_it(baseline, tmp_path, capsys):
    out = tmp_path / baseline
    assert _eval(out, "--baseline", baseline, "--seed", "3") == 0
    assert capsys.readouterr().out.strip().splitlines()[-1].startswith(f"Evaluated {baseline}")
    episodes = _check_dataset(out)
    assert list(episodes["seed"]) == [900_000_000 + 3 * 100_003, 900_000_000 + 3 * 100_003 + 1]  # paired seeds
    if baseline == "heuristic":
        assert episodes["success"].all()
    if baseline == "random":
        assert not episodes["success"].any()


@pytest.mark.parametrize("shape", ["sphere", "tetrahedron"])
def test_scripted_observed_reads_the_object_from_the_observation(shape):
    """The observed baseline's object position is the observation's (2 mm noise), mapped back to the world
    and to the body origin (a tetrahedron's is on its base): near the truth, not equal to it."""
    import gymnasium as gym

    from hingelab.envs import TOOL_PICK_ID
    from hingelab.policies.baselines import ObservedScriptedPolicy

    env = gym.make(TOOL_PICK_ID, object=shape, low_level="privileged")
    obs, _ = env.reset(seed=4)
    errors = []
    for _ in range(20):
        truth = env.unwrapped.state.object_pos_world
        errors.append(np.linalg.norm(ObservedScriptedPolicy.observed_state(env, obs).object_pos_world - truth))
        obs, *_ = env.step(np.zeros(5, np.float32))
    env.close()
    assert 0.0005 < np.mean(errors) < 0.006  # 2 mm per axis: about 3.2 mm on average


def test_same_seed_gives_the_same_episodes(tmp_path):
    runs = []
    for k in range(2):
        assert _eval(tmp_path / f"r{k}", "--baseline", "random", "--seed", "5") == 0
        runs.append(pd.read_csv(tmp_path / f"r{k}" / "episodes.csv"))
    pd.testing.assert_frame_equal(runs[0], runs[1])


def test_a_tiny_sac_checkpoint_evaluates(tmp_path, capsys):
    import gymnasium as gym
    from stable_baselines3 import SAC

    from hingelab.envs import TOOL_PICK_ID

    env = gym.make(TOOL_PICK_ID, low_level="privileged", max_episode_steps=50)
    model = SAC("MlpPolicy", env, learning_starts=100, batch_size=32, buffer_size=1000, seed=0, device="cpu",
                policy_kwargs={"net_arch": [32, 32]})
    model.learn(200)
    model.save(tmp_path / "high.zip")
    env.close()
    out = tmp_path / "eval"
    assert _eval(out, str(tmp_path / "high.zip"), "--low-level", "privileged") == 0
    assert "high.zip" in capsys.readouterr().out.strip().splitlines()[-1]
    _check_dataset(out)


def test_one_line_errors(tmp_path, capsys):
    cases = {
        "does not match ToolPick-v0": [LOW_LEVEL_ZIP],
        "learned over the low level policy": ["--low-level", LOW_LEVEL_ZIP],  # the shipped one, another low level
        "no high-level checkpoint": [str(tmp_path / "missing.zip")],
        "not both": [LOW_LEVEL_ZIP, "--baseline", "random"],
    }
    for k, (message, args) in enumerate(cases.items()):
        assert _eval(tmp_path / f"e{k}", *args) == 1
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1, err
    assert not any((tmp_path / f"e{k}").exists() for k in range(len(cases)))


def test_the_default_checkpoint_is_the_shipped_high_level_policy(tmp_path, capsys):
    """No checkpoint: the shipped assets/checkpoints/high_level.zip over the low level it learned over."""
    from hingelab.episodes.card import load_card

    out = tmp_path / "shipped"
    assert _eval(out) == 0
    assert "high_level.zip (low level policy)" in capsys.readouterr().out.strip().splitlines()[-1]
    config = load_card(out).config
    assert config["policy"].endswith("high_level.zip") and config["low_level"] == "policy"
    _check_dataset(out)


def test_failure_reasons_from_the_env_reason_and_the_episode():
    """The env's reason refined by what the episode did (first match wins; module doc)."""
    from hingelab.rollouts.high_level import FailureReasonWrapper

    wrapper = FailureReasonWrapper.__new__(FailureReasonWrapper)  # classify reads only the tracked facts

    def reason(env_reason, held=False, collided=False, closest=1.0):
        wrapper.held_ever, wrapper.collided, wrapper.closest = held, collided, closest
        return wrapper.classify(env_reason)

    assert reason("divergence", collided=True) == "divergence"
    assert reason("tool_drop", collided=True) == "tool_drop"
    assert reason("drop", held=True, collided=True) == "slip"
    assert reason("timeout", collided=True) == "table_collision"
    assert reason("timeout", closest=0.01) == "missed_grasp"
    assert reason("timeout", held=True, closest=0.0) == "timeout"
    assert reason("timeout") == "timeout"

"""The high-level reward's modes: the absorbing success term, the paper's reward by name, what saved configs
and recordings say, and the diagnostics that measure them (``hingelab diagnose reward|noise``)."""

from __future__ import annotations

import csv
import types

import numpy as np
import pytest

from hingelab.cli.main import main
from hingelab.envs.rewards import HighLevelRewardConfig, high_level_terms
from hingelab.errors import ConfigError
from hingelab.learners.sac.high_level_config import FlatTrainConfig, HighLevelTrainConfig
from hingelab.rollouts.noise_tolerance import tolerances
from hingelab.rollouts.reward_diagnostic import critic_value, step_rewards
from hingelab.training.high_level_demos import recorded_reward_config

AT_TARGET = (np.zeros(3), np.zeros(3), np.array([0.0, 0.0, 0.004]))  # tool on the object, object 4 mm off


def test_a_success_transition_carries_the_value_of_staying_at_the_target():
    config = HighLevelRewardConfig(gamma=0.98)
    terms = high_level_terms(*AT_TARGET, table_collision=False, config=config)
    r_max = 1.0 + config.c_h3
    assert terms["absorbing"] == pytest.approx(0.98 * r_max / (1 - 0.98))  # 98
    assert terms["sparse"] == config.c_h1
    total = sum(terms.values())
    assert total == pytest.approx(config.c_h1 + 1.0 + np.exp(-config.c_h4 * 0.004) + 98.0)
    # not a success: no absorbing term; the paper's mode: never one
    away = high_level_terms(np.zeros(3), np.zeros(3), np.array([0.0, 0.0, 0.011]), False, config)
    assert away["absorbing"] == 0.0 and away["sparse"] == 0.0
    paper = high_level_terms(*AT_TARGET, table_collision=False, config=HighLevelRewardConfig(mode="paper"))
    assert paper["absorbing"] == 0.0 and sum(paper.values()) == pytest.approx(total - 98.0)


def test_finishing_beats_hovering_only_under_the_absorbing_reward():
    gamma = 0.98
    hover = {"sparse": 0.0, "tool_object": 0.95, "object_target": 0.85, "penalty": 0.0}
    near = dict(hover, object_target=0.6)
    success = {"sparse": 10.0, "tool_object": 0.95, "object_target": 0.93, "penalty": 0.0}
    finishing = [near] * 5 + [success]  # five steps of carrying, then the success ends the episode
    hovering = [hover] * 150  # held 1.1 cm short until the time limit cuts the episode
    values = {}
    for mode in ("paper", "absorbing"):
        values[mode] = (critic_value(step_rewards(finishing, mode, gamma), 0, False, gamma),
                        critic_value(step_rewards(hovering, mode, gamma), 0, True, gamma))
    assert values["paper"][0] < values["paper"][1]  # lingering pays more: the flaw the issue found
    assert values["absorbing"][0] > values["absorbing"][1]
    # the bootstrap at a time-limit cut is the last reward held forever
    assert critic_value(np.array([1.0]), 0, True, 0.5) == pytest.approx(1.0 + 0.5 * 1.0 / 0.5)


def test_bad_modes_and_discounts_are_one_line_errors():
    with pytest.raises(ConfigError, match="unknown high-level reward mode 'lazy'; choose one of absorbing, paper"):
        HighLevelRewardConfig(mode="lazy")
    with pytest.raises(ConfigError, match=r"discount gamma must be in \[0, 1\)"):
        HighLevelRewardConfig(gamma=1.0)


def test_runs_train_on_the_absorbing_reward_with_their_own_discount_and_old_runs_read_as_the_papers():
    config = HighLevelTrainConfig(gamma=0.95)
    assert config.reward_mode == "absorbing"
    assert config.env_arguments()["reward"]["mode"] == "absorbing"
    assert config.env_arguments()["reward"]["gamma"] == 0.95
    assert HighLevelTrainConfig(reward_mode="paper").reward.absorbing_bonus == 0.0
    for cls in (HighLevelTrainConfig, FlatTrainConfig):
        saved = cls().to_dict()
        del saved["reward_mode"]  # a config.json written before the modes existed
        assert cls.from_dict(saved).reward_mode == "paper"
    assert HighLevelTrainConfig.from_dict(HighLevelTrainConfig().to_dict()).reward_mode == "absorbing"


def test_recordings_that_name_no_reward_config_are_read_as_the_papers():
    legacy = types.SimpleNamespace(metadata={}, path="old.mcap")
    assert recorded_reward_config(legacy) == HighLevelRewardConfig(mode="paper")
    named = types.SimpleNamespace(metadata={"reward_config": '{"mode": "absorbing", "gamma": 0.9}'}, path="new.mcap")
    assert recorded_reward_config(named) == HighLevelRewardConfig(gamma=0.9)


def test_noise_tolerance_is_the_largest_level_below_which_every_level_holds():
    rows = [{"dimension": "none", "level": 0.0, "episodes": 20, "successes": 20, "tool_drops": 0}]
    for name, outcomes in {"z_goal_0": [(20, 0), (15, 4), (19, 0)], "z_goal_1": [(19, 1), (18, 1), (17, 2)],
                           "velocity_x": [(10, 0), (20, 0), (20, 0)], "velocity_y": [(20, 0)] * 3,
                           "velocity_z": [(20, 0)] * 3}.items():
        for level, (successes, drops) in zip((0.05, 0.1, 0.2), outcomes):
            rows.append({"dimension": name, "level": level, "episodes": 20, "successes": successes,
                         "tool_drops": drops})
    assert tolerances(rows) == {"z_goal_0": 0.05, "z_goal_1": 0.1, "velocity_x": 0.0, "velocity_y": 0.2,
                                "velocity_z": 0.2}


def test_diagnose_reward_runs_the_demonstrator_and_says_which_reward_pays_finishing(tmp_path, capsys):
    assert main(["diagnose", "reward", "--episodes", "1", "--out", str(tmp_path / "reward"), "--no-progress"]) == 0
    summary = {row["mode"]: row for row in csv.DictReader(open(tmp_path / "reward" / "summary.csv"))}
    assert summary["absorbing"]["pairs"] == "1" and summary["absorbing"]["finishing_pays_more"] == "1"
    assert summary["paper"]["finishing_pays_more"] == "0"
    assert "absorbing" in (tmp_path / "reward" / "reward_diagnostic.md").read_text()


def test_diagnose_noise_writes_its_table(tmp_path):
    assert main(["diagnose", "noise", "--episodes", "1", "--levels", "0.05", "--out", str(tmp_path / "noise"),
                 "--no-progress"]) == 0
    rows = list(csv.DictReader(open(tmp_path / "noise" / "noise_tolerance.csv")))
    assert [r["dimension"] for r in rows] == ["none", "z_goal_0", "z_goal_1", "velocity_x", "velocity_y",
                                              "velocity_z"]
    assert "| velocity_z |" in (tmp_path / "noise" / "noise_tolerance.md").read_text()
    with pytest.raises(SystemExit):
        main(["diagnose", "noise", "--levels", "x", "--out", str(tmp_path)])

"""A new learner is one folder plus its registration: the example in tests/example_learner (behaviour
cloning by an MLP) trains from the command line, saves, loads through ``load_policy`` and evaluates
through ``hingelab eval high``, with no edit to hingelab."""

from __future__ import annotations

import json

import pandas as pd

import example_learner
from hingelab.cli.main import main
from hingelab.episodes.dataset import Dataset
from hingelab.learners import registry
from hingelab.policies import load_policy, policy_format


def test_the_example_learner_trains_loads_and_evaluates(tmp_path, capsys):
    assert registry.learner("high", "bc-mlp") is example_learner.BCLearner
    run = tmp_path / "bc"
    assert main(["train", "high", "--learner", "bc-mlp", "--prior-episodes", "2", "--updates", "30", "--hidden", "16",
                 "--low-level", "privileged", "--no-randomize", "--max-episode-steps", "30", "--eval-episodes", "1",
                 "--seed", "2", "--out", str(run), "--no-progress"]) == 0
    assert "Cloned the demos with an MLP" in capsys.readouterr().out
    doc = json.loads((run / "config.json").read_text())
    assert doc["learner"] == "bc-mlp" and doc["config"]["hidden"] == 16 and "gamma" not in doc["config"]
    assert len(pd.read_csv(run / "metrics.csv")) == 1

    assert policy_format(run / "model.zip").name == "example bc-mlp"
    policy = load_policy(run, level="high")  # a run folder: its model.zip
    assert isinstance(policy, example_learner.BCPolicy)
    action, state = policy.predict([0.0] * 14)
    assert action.shape == (5,) and state is None

    out = tmp_path / "eval"
    assert main(["eval", "high", str(run / "model.zip"), "--low-level", "privileged", "--episodes", "1",
                 "--out", str(out), "--no-progress"]) == 0
    assert "model.zip (low level privileged)" in capsys.readouterr().out
    assert len(Dataset(out)) == 1


def test_the_help_of_a_learner_lists_its_own_flags_only(capsys):
    for learner, own, foreign in (("bc-mlp", "--updates", "--gamma"), ("phase-clone", "--clone-members", "--gamma"),
                                  ("sac", "--gamma", "--clone-members")):
        try:
            main(["train", "high", "--learner", learner, "--help"])
        except SystemExit:
            pass
        text = capsys.readouterr().out
        assert own in text and foreign not in text, learner

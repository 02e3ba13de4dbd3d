"""The early-rollout table: a training dataset's episodes in write order, the first N env steps' successes."""

from __future__ import annotations

import os

import pandas as pd
import pytest
from scipy.stats import binomtest
from tests.test_report_numbers import HIGH_LEVEL, write_known_dataset

from hingelab.analysis.rollout_success import early_rollout_success
from hingelab.cli.main import main


def test_counts_the_episodes_that_end_within_the_first_steps_in_write_order():
    # written in the order c, a, b (mtime): lengths 40, 30, 50 -> ends 40, 70, 120
    episodes = pd.DataFrame({"dataset": "d", "dataset_path": "/d", "file": ["a", "b", "c"], "length": [30, 50, 40],
                             "success": [False, True, True], "mtime_ns": [2, 3, 1]})
    row = early_rollout_success(episodes, first_steps=70).iloc[0]
    assert (row.first_episodes, row.first_successes, row.episodes, row.successes) == (2, 1, 3, 2)
    ci = binomtest(1, 2).proportion_ci(method="wilson")
    assert row.first_rate == 0.5
    assert (row.first_ci_low, row.first_ci_high) == pytest.approx((ci.low, ci.high))
    assert early_rollout_success(episodes, first_steps=39).iloc[0].first_episodes == 0


def test_a_report_with_run_folders_writes_the_table(tmp_path):
    data = tmp_path / "run" / "dataset"
    write_known_dataset(data, "rollouts", HIGH_LEVEL)  # lengths 5, 9, 9, 4, 9; successes 1, 0, 0, 1, 0
    for k, path in enumerate(sorted(data.glob("episodes/*.mcap"))):
        os.utime(path, ns=(k, k))  # write order = name order
    (tmp_path / "run" / "metrics.csv").write_text("env_steps,seed,success_rate,return\n0,0,0.0,0.0\n")
    out = tmp_path / "report"
    assert main(["report", str(data), "--runs", str(tmp_path / "run"), "--out", str(out)]) == 0
    table = pd.read_csv(out / "early_rollouts.csv")
    assert table[["first_episodes", "episodes", "successes"]].values.tolist() == [[5, 5, 2]]
    assert "Training rollouts early on" in (out / "report.md").read_text()

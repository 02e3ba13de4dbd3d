"""bench train's equal-work rows: every loop at the same updates per env step, the overlapped loop with the fused
update against bare SB3 as the headline ratio (issue 43's target), the arms' configs as the run would get them."""

from __future__ import annotations

import pytest

from hingelab.bench.train import ARMS, UTDS, _arm_config, _equal_work_rows


def test_equal_work_rows_compare_every_arm_at_the_same_updates_per_step():
    rates = {(arm, utd): rate * utd for utd in UTDS for arm, rate in zip(ARMS, (30.0, 33.0, 45.0, 60.0))}
    rows, ratios = [], {}
    _equal_work_rows("low-level", "hingelab train low", "", rates, rows, ratios)
    assert len(rows) == 4 * len(UTDS)
    for row in rows:  # a row compares two loops at one UTD: both rates are that UTD's
        utd = 2 if "2 updates/step" in row["what"] else 1
        assert {row["baseline rate"], row["our rate"]} <= {rates[(arm, utd)] for arm in ARMS}
    assert ratios["low-level UTD 1: overlapped, fused update / bare (target: >= 1.8)"] == pytest.approx(2.0)
    assert ratios["low-level UTD 2: overlapped / serial"] == pytest.approx(45.0 / 33.0)
    fused = [row for row in rows if "--update fused" in row["ours"]]
    assert [row["baseline"] for row in fused] == ["bare SB3 SAC.learn"] * len(UTDS)


def test_the_arms_configs_differ_only_in_the_loop_and_the_update():
    from hingelab.learners.sac.low_level_config import LowLevelTrainConfig

    base = LowLevelTrainConfig(seed=0, n_envs=1)
    serial, overlap, fused = (_arm_config(base, arm, 2) for arm in ARMS[1:])
    assert (serial.overlap, overlap.overlap, fused.overlap) == (False, True, True)
    assert (serial.update, overlap.update, fused.update) == ("eager", "eager", "fused")
    assert serial.gradient_steps == overlap.gradient_steps == fused.gradient_steps == 2

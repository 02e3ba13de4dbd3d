"""hingelab diagnose families: picks split by kind and drawn size, read from real family episodes; a verdict that
names a split only when it lies below the others' interval; bad input."""

from __future__ import annotations

import pandas as pd
import pytest

from hingelab.cli.main import main
from hingelab.errors import ConfigError
from hingelab.rollouts import family_breakdown as F


def _rows(kind: str, sizes_mm, picked) -> list[dict]:
    return [{"policy": "p", "kind": kind, "size_mm": s, "first_attempt_success": ok,
             "failure_reason": "" if ok else "slip"} for s, ok in zip(sizes_mm, picked)]


def test_size_bins_label_below_between_and_above_the_edges():
    assert [F.size_bin(s, (14, 20)) for s in (8.0, 14.0, 19.9, 20.0, 30.0)] == ["<14", "14-20", "14-20", ">=20",
                                                                                ">=20"]


def test_the_verdict_names_the_small_objects_only_when_they_fall_below_the_rest():
    small_fail = _rows("disc", [10] * 20, [k < 6 for k in range(20)]) + _rows("disc", [22] * 40, [True] * 40)
    summary = F.summarize(small_fail, (14,))
    cell = next(s for s in summary if s["kind"] == "disc" and s["size_bin_mm"] == "<14")
    assert (cell["episodes"], cell["first_attempt_successes"]) == (20, 6) and cell["ci_high"] < 0.6
    assert "lowest size <14: 6/20 (0.30) against 40/40 (1.00) for the others, below their interval" in \
        F.verdict(summary, "p")
    alike = _rows("disc", [10] * 20, [k % 4 > 0 for k in range(20)]) + _rows("disc", [22] * 20,
                                                                               [k % 5 > 0 for k in range(20)])
    assert "within the noise" in F.verdict(F.summarize(alike, (14,)), "p")
    failures = F.failure_counts(small_fail)
    assert failures == [{"policy": "p", "kind": "disc", "failures": 14, "reasons": "slip 14"}]


def test_bad_bins_are_one_line_errors():
    rows = _rows("disc", [10], [True])
    for edges in ((20, 14), (0, 14), ()):
        with pytest.raises(ConfigError, match="--size-bins takes increasing positive edges"):
            F.summarize(rows, edges)


def test_diagnose_families_reads_the_draws_of_real_episodes(tmp_path, capsys):
    picks = tmp_path / "picks"
    assert main(["eval", "picks", "--baseline", "scripted", "--sets", "family:washer:0.03", "--episodes", "2",
                 "--seed", "7", "--no-progress", "--out", str(picks)]) == 0
    out = tmp_path / "families"
    assert main(["diagnose", "families", str(picks / "family_washer_30mm"), "--size-bins", "14", "20",
                 "--out", str(out), "--allow-dirty"]) == 0
    assert "scripted: " in capsys.readouterr().out
    episodes = pd.read_csv(out / "episodes.csv")
    recorded = pd.read_csv(picks / "family_washer_30mm" / "episodes.csv")
    assert list(episodes["kind"]) == ["washer", "washer"] and episodes["size_mm"].between(8, 30).all()
    assert {"param_inner", "param_thickness"} <= set(episodes.columns)
    assert sorted(episodes["first_attempt_success"]) == sorted(recorded["first_attempt_success"])
    summary = pd.read_csv(out / "summary.csv")
    pooled = summary[(summary.kind == "all") & (summary.size_bin_mm == "all")].iloc[0]
    assert pooled.episodes == 2 and pooled.first_attempt_successes == recorded["first_attempt_success"].sum()
    assert "| washer |" in (out / "families.md").read_text()


def test_a_dataset_of_fixed_objects_is_refused_by_name(tmp_path, capsys):
    picks = tmp_path / "picks"
    assert main(["eval", "picks", "--baseline", "random", "--sets", "cube:0.015", "--episodes", "1", "--seed", "7",
                 "--no-progress", "--out", str(picks)]) == 0
    assert main(["diagnose", "families", str(picks / "cube_15mm"), "--out", str(tmp_path / "f"),
                 "--allow-dirty"]) == 1
    err = capsys.readouterr().err
    assert "no object draw" in err and "family:NAME" in err and len(err.strip().splitlines()) == 1

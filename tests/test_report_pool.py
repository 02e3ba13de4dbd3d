"""``hingelab report --pool``: pooled and per-region success over evaluation folders, from episodes.csv
files of the old layout (``success`` = last step, ``settled_success``) and the new one (``success`` =
settled, ``last_step_success``), with Wilson intervals; a bad folder is a one-line error naming it."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from hingelab import provenance
from hingelab.analysis.pooled import load_folder, opening_bands, pool_name
from hingelab.analysis.wilson import wilson_interval
from hingelab.cli.main import main

# 10 goals: opening, third, settled verdict, last-step verdict, largest drift (mm), tip-gap error (mm)
GOALS = pd.DataFrame({
    "goal_opening_rad": [0.02, 0.05, 0.09, 0.10, 0.15, 0.17, 0.19, 0.21, 0.23, 0.25],
    "region": ["closed", "closed", "closed", "middle", "middle", "middle", "open", "open", "open", "open"],
    "settled": [True, True, False, True, True, True, True, False, True, True],
    "last_step": [False, True, False, False, True, False, False, False, True, False],
    "drift": [2.0, 12.0, 3.0, 4.0, 5.0, 6.0, 15.0, 7.0, 8.0, 30.0],
    "tip_gap": [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0],
})


def _common(goals: pd.DataFrame) -> dict:
    return {"region": goals["region"], "goal_opening_rad": goals["goal_opening_rad"], "seed": range(len(goals)),
            "tip_gap_error_mm": goals["tip_gap"], "tool_drift_mm_max": goals["drift"], "length": 50}


def write_old(folder, goals=GOALS):
    """An episodes.csv as `hingelab eval low` wrote it before schema 2: success = the last step's verdict."""
    folder.mkdir(parents=True)
    c = _common(goals)
    pd.DataFrame({"region": c["region"], "goal_opening_rad": c["goal_opening_rad"], "seed": c["seed"],
                  "success": goals["last_step"], "final_latent_distance": 0.1,
                  "settled_success": goals["settled"], "settled_latent_distance": 0.05,
                  "tip_gap_error_mm": c["tip_gap_error_mm"], "final_hinge_rad": 0.1, "return": 30.0,
                  "length": 50, "tool_drift_mm_max": c["tool_drift_mm_max"], "failure_reason": ""}
                 ).to_csv(folder / "episodes.csv", index=False)
    return folder


def write_new(folder, goals=GOALS):
    """An episodes.csv of the new layout: success = the settled verdict, last_step_success secondary."""
    folder.mkdir(parents=True)
    c = _common(goals)
    pd.DataFrame({"region": c["region"], "goal_opening_rad": c["goal_opening_rad"], "seed": c["seed"],
                  "success": goals["settled"], "settled_latent_distance": 0.05,
                  "last_step_success": goals["last_step"], "final_latent_distance": 0.1,
                  "tip_gap_error_mm": c["tip_gap_error_mm"], "final_hinge_rad": 0.1, "return": 30.0,
                  "length": 50, "tool_drift_mm_max": c["tool_drift_mm_max"], "failure_reason": ""}
                 ).to_csv(folder / "episodes.csv", index=False)
    return folder


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("hingelab: error: "), err
    return err[0]


def _wilson(k, n):
    low, high = wilson_interval(np.array([k]), np.array([n]))
    return float(low[0]), float(high[0])


def test_both_layouts_count_the_settled_verdict(tmp_path, capsys):
    old = write_old(tmp_path / "evals" / "policy_seed3")
    # the new-layout folder: the same goals with two more failures (8 settled -> 6)
    second = GOALS.copy()
    second.loc[[0, 4], "settled"] = False
    new = write_new(tmp_path / "evals" / "policy_seed4", second)
    out = tmp_path / "pooled"
    assert main(["report", "--pool", str(old), str(new), "--out", str(out)]) == 0
    summary = capsys.readouterr().out
    assert "policy_seed3,4" in summary and "14/20" in summary
    assert sorted(p.name for p in out.iterdir()) == ["by_region.csv", "pooled.csv", "pooled.md"]

    pooled = pd.read_csv(out / "pooled.csv")
    assert list(pooled["folder"]) == [str(old), str(new), "pooled"]
    assert list(pooled["layout"]) == ["old", "new", "old+new"]
    assert list(pooled["episodes"]) == [10, 10, 20]
    assert list(pooled["successes"]) == [8, 6, 14]  # settled, never the old file's last-step `success` (3)
    assert list(pooled["last_step_successes"]) == [3, 3, 6]
    # settled and the tool's largest drift under 10 mm: goals 0, 3, 4, 5, 8 (old); 3, 5, 8 (new)
    assert list(pooled["successes_drift_under_1cm"]) == [5, 3, 8]
    for row in pooled.itertuples():
        assert row.success_rate == pytest.approx(row.successes / row.episodes)
        assert (row.ci_low, row.ci_high) == pytest.approx(_wilson(row.successes, row.episodes), abs=1e-12)
        assert (row.drift_ci_low, row.drift_ci_high) == pytest.approx(
            _wilson(row.successes_drift_under_1cm, row.episodes), abs=1e-12)
    pooled_row = pooled.iloc[-1]
    assert pooled_row["tip_gap_error_mm_median"] == pytest.approx(0.55)
    assert pooled_row["tool_drift_mm_max_median"] == pytest.approx(np.median(list(GOALS["drift"]) * 2))

    markdown = (out / "pooled.md").read_text()
    assert "| settled_success (old layout) |" in markdown and "| success |" in markdown
    assert "hingelab report --pool" in markdown and "0.700 [0.481, 0.855] (14/20)" in markdown


def test_per_region_split(tmp_path):
    old = write_old(tmp_path / "a_seed1")
    out = tmp_path / "pooled"
    assert main(["report", "--pool", str(old), "--out", str(out)]) == 0
    pooled = pd.read_csv(out / "pooled.csv")
    assert list(pooled["folder"]) == [str(old)]  # one folder: no separate pooled row
    regions = pd.read_csv(out / "by_region.csv").set_index(["split", "region"])
    thirds = regions.loc["goal_third"]
    assert thirds.loc["closed", ["episodes", "successes", "successes_drift_under_1cm"]].tolist() == [3, 2, 1]
    assert thirds.loc["middle", ["episodes", "successes", "successes_drift_under_1cm"]].tolist() == [3, 3, 3]
    assert thirds.loc["open", ["episodes", "successes", "successes_drift_under_1cm"]].tolist() == [4, 3, 1]
    bands = regions.loc["opening_band"]
    assert list(bands.index) == ["< 0.10", "0.10-0.18", "0.18-0.22", ">= 0.22"]
    # 0.10 itself belongs to 0.10-0.18 (bands are left-closed)
    assert bands["episodes"].tolist() == [3, 3, 2, 2]
    assert bands["successes"].tolist() == [2, 3, 1, 2]
    assert bands["successes_drift_under_1cm"].tolist() == [1, 3, 0, 1]
    for (_, row) in regions.iterrows():
        assert (row.ci_low, row.ci_high) == pytest.approx(_wilson(row.successes, row.episodes), abs=1e-12)
    assert bands.loc[">= 0.22", "tool_drift_mm_max_median"] == pytest.approx(19.0)


def test_custom_bands_names_and_a_bare_episodes_csv(tmp_path):
    old = write_old(tmp_path / "x")
    out = tmp_path / "pooled"
    assert main(["report", "--pool", str(old / "episodes.csv"), "--pool-name", "mine", "--bands", "0.2",
                 "--title", "T", "--out", str(out)]) == 0
    regions = pd.read_csv(out / "by_region.csv")
    bands = regions[regions["split"] == "opening_band"]
    assert bands["region"].tolist() == ["< 0.20", ">= 0.20"] and bands["episodes"].tolist() == [7, 3]
    assert set(regions["pool"]) == {"mine"}
    markdown = (out / "pooled.md").read_text()
    assert markdown.startswith("# T\n") and "--pool-name mine --bands 0.2 --title T" in markdown


def test_pool_names_and_bands():
    assert pool_name(["e/experts_goals_seed3", "e/experts_goals_seed4", "e/experts_goals_seed5"]) \
        == "experts_goals_seed3-5"
    assert pool_name(["a_seed2", "a_seed4"]) == "a_seed2,4"
    assert pool_name(["x/episodes.csv", "y/episodes.csv"]) == "x+y"
    bands = opening_bands(pd.Series([0.0999, 0.10, 0.18, 0.2199, 0.22, np.nan]), (0.10, 0.18, 0.22))
    assert bands.tolist()[:5] == ["< 0.10", "0.10-0.18", "0.18-0.22", "0.18-0.22", ">= 0.22"]
    assert pd.isna(bands.iloc[5])


def test_bad_folders_are_one_line_errors(tmp_path, capsys):
    good = write_old(tmp_path / "good")
    out = tmp_path / "pooled"
    missing = tmp_path / "nope_seed9"
    assert main(["report", "--pool", str(good), str(missing), "--out", str(out)]) == 1
    assert str(missing) in one_line_error(capsys) and not out.exists()
    (tmp_path / "empty").mkdir()
    assert main(["report", "--pool", str(tmp_path / "empty"), "--out", str(out)]) == 1
    err = one_line_error(capsys)
    assert str(tmp_path / "empty") in err and "episodes.csv" in err
    bad = tmp_path / "bad"
    bad.mkdir()
    pd.DataFrame({"region": ["closed"], "success": [True]}).to_csv(bad / "episodes.csv", index=False)
    assert main(["report", "--pool", str(bad), "--out", str(out)]) == 1
    assert "goal_opening_rad" in one_line_error(capsys)
    assert main(["report", str(good), "--pool", str(good), "--out", str(out)]) == 1
    assert "not both" in one_line_error(capsys)
    assert main(["report", "--out", str(out)]) == 1
    assert "DATASET" in one_line_error(capsys)
    assert main(["report", "--pool", str(good), "--pool", str(good), "--out", str(out)]) == 1
    assert "same name" in one_line_error(capsys)


def test_refuses_dirty_code_under_analysis_unless_allowed(tmp_path, monkeypatch, capsys):
    good = write_new(tmp_path / "good")
    analysis = tmp_path / "analysis"
    monkeypatch.setattr(provenance, "ANALYSIS_DIR", analysis)
    monkeypatch.setattr(provenance, "is_dirty", lambda version=None: True)
    monkeypatch.setattr(provenance, "dirty_files", lambda: ["platform/hingelab/x.py"])
    monkeypatch.setattr(provenance, "_ignored", lambda path: False)
    out = analysis / "pooled"
    assert main(["report", "--pool", str(good), "--out", str(out)]) == 1
    assert "--allow-dirty" in one_line_error(capsys) and not out.exists()
    assert main(["report", "--pool", str(good), "--out", str(out), "--allow-dirty"]) == 0
    assert (out / "pooled.md").exists()


def test_an_evaluation_dataset_without_episodes_csv(tmp_path):
    from hingelab.episodes import create_dataset
    from hingelab.episodes.synthetic import write_synthetic_episode

    root = tmp_path / "eval_ds"
    create_dataset(root, name="eval", source="synthetic", config={}, seed=0)
    for seed in range(4):  # even seeds succeed
        write_synthetic_episode(root, seed=seed, n_steps=3, extra_metadata={
            "goal_region": ("closed", "open")[seed // 2], "goal_opening_rad": f"{0.05 + 0.06 * seed:.5f}"})
    folder = load_folder(root)
    assert folder.layout == "dataset" and folder.episodes["verdict"].sum() == 2
    out = tmp_path / "pooled"
    assert main(["report", "--pool", str(root), "--out", str(out)]) == 0
    regions = pd.read_csv(out / "by_region.csv").set_index(["split", "region"])
    assert regions.loc[("goal_third", "closed"), "episodes"] == 2
    assert regions.loc[("opening_band", "0.10-0.18"), "episodes"] == 2  # 0.11, 0.17
    pooled = pd.read_csv(out / "pooled.csv")
    assert pooled["successes"].tolist() == [2] and pooled["successes_drift_under_1cm"].isna().all()
    assert "n/a" in (out / "pooled.md").read_text()

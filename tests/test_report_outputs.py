"""``hingelab report`` writes md, html, PNGs and CSVs, learning curves from run folders, and
refuses bad input with one line."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from mcap.writer import Writer

from hingelab.analysis.learning_curves import load_learning_curves, seed_summary
from hingelab.cli.main import main
from hingelab.episodes import create_dataset
from hingelab.episodes.synthetic import write_synthetic_episode


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("data") / "synthetic"
    create_dataset(root, name="synthetic", source="synthetic", config={"n": 6}, seed=0)
    for seed in range(6):  # even seeds succeed, odd seeds time out
        write_synthetic_episode(root, seed=seed, n_steps=5, object=("sphere", "cube")[seed % 3 == 0])
    return root


def write_run(run_dir, seeds=(0, 1, 2)):
    """A training run folder in the documented format: metrics.csv (env_steps, seed, success_rate, return)."""
    run_dir.mkdir(parents=True)
    rows = [{"env_steps": steps, "seed": seed, "success_rate": min(1.0, steps / 4000 + 0.1 * seed),
             "return": steps / 100 + seed} for seed in seeds for steps in (0, 1000, 2000, 3000)]
    pd.DataFrame(rows).to_csv(run_dir / "metrics.csv", index=False)


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("hingelab: error: "), err
    return err[0]


def test_report_files_and_learning_curves(dataset, tmp_path, capsys):
    write_run(tmp_path / "runs" / "sac_a")
    per_seed = tmp_path / "runs" / "sac_b"
    for seed in (0, 1):  # one subfolder per seed
        write_run(per_seed / f"seed{seed}", seeds=(seed,))
    out = tmp_path / "report"
    argv = ["report", str(dataset), "--runs", str(tmp_path / "runs" / "sac_a"), str(per_seed), "--out", str(out)]
    assert main(argv) == 0
    summary = capsys.readouterr().out.strip().splitlines()[-1]
    assert "Counted 6 episodes" in summary and "overall success 0.500" in summary
    for name in ("report.md", "report.html", "report.json", "episodes.csv", "attempts.csv", "learning_curves.csv"):
        assert (out / name).stat().st_size > 100, name
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert pngs == ["attempts.png", "learning_curves.png", "learning_curves_by_seed.png", "lengths.png", "returns.png",
                    "success_by_object.png", "success_by_source.png"]
    for png in out.glob("*.png"):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 5000
    page = (out / "report.html").read_text()
    assert all(f"src='{name}'" in page for name in pngs)
    assert "<td>0.500</td>" in page  # the overall rate in a table
    markdown = (out / "report.md").read_text()
    assert "| synthetic | cube | 2 | 1 | 0.500 |" in markdown  # cubes: seeds 0 (success) and 3 (timeout)
    curves = pd.read_csv(out / "learning_curves.csv")
    a = curves[curves.run == "sac_a"].set_index("env_steps")
    assert a.loc[2000, "seeds"] == 3
    assert a.loc[2000, "success_rate_mean"] == pytest.approx(np.mean([0.5, 0.6, 0.7]))
    assert a.loc[2000, "success_rate_std"] == pytest.approx(np.std([0.5, 0.6, 0.7], ddof=1))
    b = curves[curves.run == "sac_b"].set_index("env_steps")
    assert b.loc[3000, "seeds"] == 2 and b.loc[3000, "return_mean"] == pytest.approx(30.5)
    # every seed's own curve under the mean (the ablation's plot)
    by_seed = pd.read_csv(out / "learning_curves_by_seed.csv")
    assert len(by_seed) == 4 * (3 + 2) and set(by_seed.groupby("run")["seed"].nunique()) == {3, 2}
    assert by_seed.set_index(["run", "seed", "env_steps"]).loc[("sac_a", 1, 2000), "success_rate"] == \
        pytest.approx(0.6)
    assert "return" in by_seed.columns  # the paper's Fig. 5a plots the return: per seed too
    # per seed: the first evaluation at success >= 0.5 (success = steps / 4000 + 0.1 seed), and the last
    seeds = pd.read_csv(out / "seeds.csv").set_index(["run", "seed"])
    assert seeds.loc[("sac_a", 0), "env_steps_to_0.5"] == 2000 and seeds.loc[("sac_a", 2), "env_steps_to_0.5"] == 2000
    assert seeds.loc[("sac_b", 1), "env_steps_to_0.5"] == 2000 and seeds.loc[("sac_a", 0), "last_success_rate"] == 0.75
    # whether a run keeps its start (Fig. 5a's privileged arm): these curves only rise, so no drop
    assert seeds.loc[("sac_a", 0), "start_success_rate"] == seeds.loc[("sac_a", 0), "lowest_success_rate"]
    assert (seeds["largest_drop_below_start"] == 0).all()
    assert seeds.loc[("sac_a", 0), "last_minus_start"] == pytest.approx(0.75 - seeds.loc[("sac_a", 0),
                                                                                       "start_success_rate"])


def test_seed_table_reports_the_drop_below_the_start():
    seeds = pd.DataFrame({"run": "priv", "seed": 0, "env_steps": [0, 10, 20, 30],
                          "success_rate": [0.9, 1.0, 0.8, 0.95]}).sample(frac=1.0, random_state=0)  # any row order
    row = seed_summary(seeds).iloc[0]
    assert row["start_success_rate"] == 0.9 and row["lowest_success_rate"] == 0.8
    assert row["largest_drop_below_start"] == pytest.approx(0.1)
    assert row["last_minus_start"] == pytest.approx(0.05) and row["last_success_rate"] == 0.95


def test_learning_curves_need_the_documented_columns(tmp_path):
    run = tmp_path / "bad_run"
    run.mkdir()
    pd.DataFrame({"steps": [0], "success": [0.0]}).to_csv(run / "metrics.csv", index=False)
    with pytest.raises(Exception, match="lacks the column"):
        load_learning_curves([run])


def test_bad_input_is_one_line(dataset, tmp_path, capsys):
    out = str(tmp_path / "out")
    assert main(["report", str(tmp_path / "nope"), "--out", out]) == 1
    assert "does not exist" in one_line_error(capsys)

    empty = tmp_path / "empty"
    create_dataset(empty, name="empty", source="synthetic", config={}, seed=0)
    (empty / "episodes").mkdir(exist_ok=True)
    assert main(["report", str(empty), "--out", out]) == 1
    assert "has no episodes" in one_line_error(capsys)

    no_outcomes = tmp_path / "no_outcomes"
    create_dataset(no_outcomes, name="no_outcomes", source="foreign", config={}, seed=0)
    (no_outcomes / "episodes").mkdir(exist_ok=True)
    with open(no_outcomes / "episodes" / "foreign-1.mcap", "wb") as stream:  # another writer: no 'success'
        writer = Writer(stream)
        writer.start()
        writer.add_metadata("episode", {"source": "foreign", "object": "sphere", "seed": "1", "schema_version": "1"})
        writer.finish()
    assert main(["report", str(no_outcomes), "--out", out]) == 1
    assert "records 'success'" in one_line_error(capsys)

    assert main(["report", str(dataset), "--runs", str(tmp_path / "no_run"), "--out", out]) == 1
    assert "run folder" in one_line_error(capsys)


@pytest.mark.parametrize("verb", ["report", "view"])
def test_help_of_the_verbs(verb, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([verb, "--help"])
    assert exit_info.value.code == 0
    assert ("Wilson 95% intervals" if verb == "report" else "--cloud-every") in capsys.readouterr().out


def test_learning_curves_draw_the_optional_metrics_every_run_records(tmp_path):
    """A run that records the secondary last-step verdict gets its panel; a hingelab train low
    metrics.csv written before schema 2 (success_rate = last step, settled_success_rate) is read
    with the settled verdict as success_rate, so old and new runs plot the same verdict."""
    from hingelab.analysis.learning_curves import load_learning_curves
    from hingelab.analysis.plots import learning_curve_plot

    write_run(tmp_path / "new")  # today's columns: success_rate (settled) and last_step_success_rate
    metrics = pd.read_csv(tmp_path / "new" / "metrics.csv")
    metrics["last_step_success_rate"] = metrics["success_rate"] / 2
    metrics.to_csv(tmp_path / "new" / "metrics.csv", index=False)
    write_run(tmp_path / "old")  # before schema 2: success_rate = last step, settled_success_rate = settled
    metrics = pd.read_csv(tmp_path / "old" / "metrics.csv")
    metrics["settled_success_rate"], metrics["success_rate"] = metrics["success_rate"], metrics["success_rate"] / 2
    metrics.to_csv(tmp_path / "old" / "metrics.csv", index=False)
    curves = load_learning_curves([tmp_path / "new", tmp_path / "old"])
    for run in ("new", "old"):
        row = curves[(curves.run == run) & (curves.env_steps == 2000)].iloc[0]
        assert row["success_rate_mean"] == pytest.approx(np.mean([0.5, 0.6, 0.7])), run
        assert row["last_step_success_rate_mean"] == pytest.approx(np.mean([0.25, 0.3, 0.35])), run
    assert "settled_success_rate_mean" not in curves and "final_latent_distance_mean" not in curves
    png = learning_curve_plot(curves, tmp_path / "curves.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # a learning_curves.csv written before schema 2 (settled_success_rate_* columns) still plots
    old_table = curves.rename(columns={"last_step_success_rate_mean": "settled_success_rate_mean",
                                       "last_step_success_rate_std": "settled_success_rate_std"})
    assert learning_curve_plot(old_table, tmp_path / "old.png").stat().st_size > 5000


# regions.csv of hingelab eval low before schema 2 (analysis/low-level-experts/experts_goals_seed3's header,
# its "all" row): success_* = the last step, settled_* = the verdict
OLD_REGIONS = """goal_region,episodes,successes,success_rate,ci_low,ci_high,success_and_drift_under_1cm,\
settled_successes,settled_success_rate,settled_ci_low,settled_ci_high,settled_success_and_drift_under_1cm,\
final_latent_distance,settled_latent_distance,tip_gap_error_mm_median,tool_drift_mm_max_median
all,100,72,0.72,0.6251,0.7986,0.69,95,0.95,0.8882,0.9785,0.92,0.0680,0.0313,0.5168,3.2365
"""


def test_low_level_summary_reads_old_and_new_region_tables(tmp_path):
    from hingelab.analysis.low_level_summary import write_summary

    old, new = tmp_path / "old_eval", tmp_path / "new_eval"
    old.mkdir()
    new.mkdir()
    (old / "regions.csv").write_text(OLD_REGIONS)
    # the same evaluation as today's eval low writes it: the verdict unprefixed, last_step_* secondary
    pd.DataFrame([{"goal_region": "all", "episodes": 100, "successes": 95, "success_rate": 0.95, "ci_low": 0.8882,
                   "ci_high": 0.9785, "success_and_drift_under_1cm": 0.92, "last_step_successes": 72,
                   "last_step_success_rate": 0.72, "last_step_ci_low": 0.6251, "last_step_ci_high": 0.7986,
                   "last_step_success_and_drift_under_1cm": 0.69, "final_latent_distance": 0.0680,
                   "settled_latent_distance": 0.0313, "tip_gap_error_mm_median": 0.5168,
                   "tool_drift_mm_max_median": 3.2365}]).to_csv(new / "regions.csv", index=False)
    table = write_summary(tmp_path / "summary", [old, new])
    assert table.loc[0].drop("policy").to_dict() == table.loc[1].drop("policy").to_dict()
    assert table.loc[0, "success"] == "0.95 [0.89, 0.98]" and table.loc[0, "success_last_step"] == "0.72 [0.63, 0.80]"
    assert table.loc[0, "success_and_drift_under_1cm"] == 0.92
    assert (tmp_path / "summary.md").read_text().startswith("success: ToolShape-v0's verdict, z_bar averaged over")


def test_report_says_which_verdict_it_counts_for_old_and_new_episodes(tmp_path):
    """Episodes of schema 2 name their verdict (success_verdict); a ToolShape-v0 episode written
    before (schema 1, no success_verdict) counted the last step, and the report says so; an index
    written before the column existed is rebuilt; a foreign task's verdict is unnamed."""
    import io

    from hingelab.episodes import EpisodeWriter, create_dataset
    from hingelab.episodes.card import INDEX_FILE
    from hingelab.episodes.dataset import Dataset

    def episodes(root, name, task, facts, successes):
        create_dataset(root, name=name, source="low_level_evaluation", config={"name": name}, seed=0)
        for seed, success in enumerate(successes):
            with EpisodeWriter(root, source="low_level_evaluation", task=task, seed=seed,
                               extra_metadata=facts) as writer:
                writer.write_step(0.0, latent_z=np.zeros(2))
                writer.set_outcome(success=success)

    shape = "hingelab/ToolShape-v0"
    episodes(tmp_path / "old", "old", shape, {"schema_version": 1}, [True, False, False])
    episodes(tmp_path / "new", "new", shape, {"success_verdict": "settled_0.5s", "last_step_success": False},
             [True, True, False, True])
    episodes(tmp_path / "foreign", "foreign", "some_task", {}, [True])
    # the old dataset's index as code before schema 2 wrote it: without the new columns
    old_index = Dataset(tmp_path / "old").index.drop(columns=["success_verdict", "last_step_success"])
    buffer = io.BytesIO()
    old_index.to_parquet(buffer, index=False)
    (tmp_path / "old" / INDEX_FILE).write_bytes(buffer.getvalue())
    index = Dataset(tmp_path / "old").index
    assert index["success_verdict"].isna().all() and (index["schema_version"] == 1).all()
    new_index = Dataset(tmp_path / "new").index
    assert (new_index["success_verdict"] == "settled_0.5s").all() and (new_index["schema_version"] >= 2).all()
    assert not new_index["last_step_success"].any()

    out = tmp_path / "report"
    assert main(["report", str(tmp_path / "old"), str(tmp_path / "new"), str(tmp_path / "foreign"),
                 "--out", str(out)]) == 0
    by_dataset = pd.read_csv(out / "success_by_dataset.csv").set_index("dataset")
    assert by_dataset.loc["old", "verdict"] == "last step (ToolShape-v0, recorded before schema v2)"
    assert by_dataset.loc["new", "verdict"] == "settled over the last 0.5 s (ToolShape-v0)"
    assert by_dataset.loc["foreign", "verdict"] == "as its source recorded it (no success_verdict)"
    assert by_dataset["successes"].to_dict() == {"foreign": 1, "new": 3, "old": 1}
    by_source = pd.read_csv(out / "success_by_source.csv")  # one source, two verdicts: both named
    assert by_source.loc[0, "verdict"].count(";") == 2
    markdown = (out / "report.md").read_text()
    assert ("What success counts: foreign (low_level_evaluation): as its source recorded it (no success_verdict); "
            "new (low_level_evaluation): settled over the last 0.5 s (ToolShape-v0); old (low_level_evaluation): "
            "last step (ToolShape-v0, recorded before schema v2).") in markdown
    assert "last step (ToolShape-v0, recorded before schema v2)" in (out / "report.html").read_text()
    table = pd.read_csv(out / "episodes.csv")
    assert table.loc[table["dataset"] == "new", "success_verdict"].eq("settled_0.5s").all()
    assert table.loc[table["dataset"] == "old", "success_verdict"].isna().all()

"""``hingelab report`` writes md, html, PNGs and CSVs, learning curves from run folders, and
refuses bad input with one line."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from mcap.writer import Writer

from hingelab.analysis.learning_curves import load_learning_curves
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
    assert pngs == ["attempts.png", "learning_curves.png", "lengths.png", "returns.png",
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
    from hingelab.analysis.learning_curves import load_learning_curves
    from hingelab.analysis.plots import learning_curve_plot

    for name in ("with_effort", "without"):
        write_run(tmp_path / name)
        metrics = pd.read_csv(tmp_path / name / "metrics.csv")
        metrics["settled_success_rate"] = metrics["success_rate"] / 2
        metrics.to_csv(tmp_path / name / "metrics.csv", index=False)
    curves = load_learning_curves([tmp_path / "with_effort", tmp_path / "without"])
    row = curves[(curves.run == "without") & (curves.env_steps == 2000)].iloc[0]
    assert row["settled_success_rate_mean"] == pytest.approx(np.mean([0.25, 0.3, 0.35]))
    assert "final_latent_distance_mean" not in curves  # not recorded: not drawn
    png = learning_curve_plot(curves, tmp_path / "curves.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

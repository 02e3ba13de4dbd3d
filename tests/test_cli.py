"""The ``hingelab`` command as a user runs it, checked output. One test starts it as a real subprocess
(``python -m hingelab.cli.main``: exit status, a closed pipe); the others call ``main`` in this process, the
same parser and commands without a process start (a few seconds each: the parser imports every command)."""

from __future__ import annotations

import json
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest


def in_process(capsys, *args) -> tuple[int, str, str]:
    """``hingelab *args`` run by ``main`` here: exit code, stdout, stderr."""
    from hingelab.cli.main import main

    capsys.readouterr()
    try:
        code = main(list(args))
    except SystemExit as exc:  # argparse's --help
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def test_help_lists_the_commands(capsys):
    code, out, _ = in_process(capsys, "--help")
    assert code == 0
    for verb in ("demo", "bench", "datasets"):
        assert verb in out


def test_demo_runs_and_measures_the_platform(tmp_path, capsys):
    """In process: the session's shared registration maps (conftest) serve the demo's envs too."""
    out_file = tmp_path / "demo.json"
    code, stdout, _ = in_process(capsys, "demo", "--out", str(out_file))
    assert code == 0
    result = types.SimpleNamespace(stdout=stdout)
    assert "lifted it" in result.stdout and "demo finished" in result.stdout
    measured = json.loads(out_file.read_text())["step_platform"]
    assert measured["hold_drift_mm"] < 5
    assert measured["finger_hinge_range_rad"][1] - measured["finger_hinge_range_rad"][0] > 0.15
    assert measured["reach_worst_error_mm"] < 2 and not measured["reach_table_collision"]
    assert measured["lift_cm"] > 4.5
    low = json.loads(out_file.read_text())["step_low_level_policy"]  # the shipped low-level policy
    assert len(low["tip_gap_error_mm"]) == 3 and low["episodes"] == 3
    # one verdict: what the demo printed is what its dataset records and what the report counts
    from hingelab.episodes.dataset import Dataset

    index = Dataset(low["dataset"]).index
    assert len(index) == 3 and (index["success_verdict"] == "settled_0.5s").all()
    assert low["successes"] == int(index["success"].sum())
    assert low["success_rate"] == pytest.approx(index["success"].mean())
    assert low["last_step_success_rate"] == pytest.approx(index["last_step_success"].astype(float).mean())
    assert f"low_level_experts.json: success {low['successes']}/3 (settled over the last 0.5 s)" in result.stdout
    reported = json.loads(out_file.read_text())["step_report_and_recording"]["by_dataset"]  # by card name
    low_name = Dataset(low["dataset"]).card.name
    assert reported[low_name]["successes"] == low["successes"] and reported[low_name]["episodes"] == 3
    assert reported[low_name]["verdict"] == "settled over the last 0.5 s (ToolShape-v0)"
    assert f"{low_name} {low['successes']}/3 (settled over the last 0.5 s (ToolShape-v0))" in result.stdout
    heuristic = json.loads(out_file.read_text())["step_heuristic_demos"]
    heuristic_index = Dataset(heuristic["dataset"]).index
    assert (heuristic_index["success_verdict"] == "object_within_1cm").all()
    reported_heuristic = reported[Dataset(heuristic["dataset"]).card.name]
    assert reported_heuristic["successes"] == int(heuristic_index["success"].sum())
    assert reported_heuristic["success_rate"] == pytest.approx(heuristic["success_rate"])
    assert reported_heuristic["verdict"] == "object within 1 cm of the target (ToolPick-v0)"
    # the scripted high level over the shipped low-level policy: printed = recorded = reported
    hierarchy = json.loads(out_file.read_text())["step_scripted_hierarchy"]
    hierarchy_index = Dataset(hierarchy["dataset"]).index
    assert len(hierarchy_index) == hierarchy["episodes"] == 2
    assert (hierarchy_index["source"] == "high_level_evaluation").all()
    assert hierarchy["successes"] == int(hierarchy_index["success"].sum())
    assert reported[Dataset(hierarchy["dataset"]).card.name]["successes"] == hierarchy["successes"]
    assert f"success {hierarchy['successes']}/2 (object within 1 cm of the target)" in result.stdout
    # the rig's ROS 2 bag: imported as real episodes (reported with the others) and exported back
    real = json.loads(out_file.read_text())["step_ros2_bags"]
    assert real["episodes"] == 3 and real["steps"] == 75 and real["dropped"] == 0 and real["exported_bags"] == 3
    real_index = Dataset(real["dataset"]).index
    assert (real_index["source"] == "real").all() and int(real_index["success"].sum()) == 2
    assert reported[Dataset(real["dataset"]).card.name]["successes"] == 2
    # the sweep on a local one-node Ray: 2 conditions x 1 seed, each a finished run folder, in the report
    import pandas as pd

    sweep = json.loads(out_file.read_text())["step_sweep"]
    table = pd.read_csv(sweep["sweep_csv"]).set_index("trial")
    assert sorted(table.index) == ["effort_seed0", "no_effort_seed0"]
    assert (table["state"] == "finished").all() and (table["env_steps"] == 40).all()
    for trial, row in table.iterrows():
        assert sweep["trials"][trial]["final_success_rate"] == pytest.approx(row["final_success_rate"])
        metrics = pd.read_csv(f"{sweep['sweep']}/{trial}/metrics.csv")
        assert list(metrics["env_steps"]) == [0, 20, 40]
        assert row["final_success_rate"] == pytest.approx(metrics["success_rate"].iloc[-1])
    assert "sweep.csv:" in result.stdout and "2 of 2 trials of `hingelab train low` finished" in result.stdout
    report_dir = Path(json.loads(out_file.read_text())["step_report_and_recording"]["report"]).parent
    final = pd.read_csv(report_dir / "final_success.csv").set_index("run")
    assert sorted(final.index) == ["effort", "no_effort"] and (final["seeds"] == 1).all()
    for condition in ("effort", "no_effort"):
        assert final.loc[condition, "success_rate_mean"] == pytest.approx(
            table.loc[f"{condition}_seed0", "final_success_rate"])
    # the shipped high-level policy (once shipped): printed = recorded = reported
    learned = json.loads(out_file.read_text())["step_learned_hierarchy"]
    from hingelab.policies.high_level import SHIPPED_HIGH_LEVEL

    assert learned.get("skipped", False) == (not SHIPPED_HIGH_LEVEL.exists())
    if not learned.get("skipped"):
        learned_index = Dataset(learned["dataset"]).index
        assert len(learned_index) == learned["episodes"] == 2
        assert learned["successes"] == int(learned_index["success"].sum())
        assert reported[Dataset(learned["dataset"]).card.name]["successes"] == learned["successes"]


def test_bench_sim_writes_its_table(tmp_path, capsys):
    code, stdout, _ = in_process(capsys, "bench", "sim", "--quick", "--out", str(tmp_path))
    assert code == 0
    result = types.SimpleNamespace(stdout=stdout)
    assert "SimCore / raw mj_step" in result.stdout
    table = json.loads((tmp_path / "sim.json").read_text())
    assert {row["scene"] for row in table["rows"]} == {"tool_shape", "tool_pick"}
    # each ratio is the table's own figures, ours / baseline, from its rows; the figures are real rates
    assert set(table["ratios"]) == {f"{row['scene']}: SimCore / raw mj_step" for row in table["rows"]}
    for row in table["rows"]:
        ours, raw = row["SimCore.step (control steps/s)"], row["raw mj_step (control steps/s)"]
        assert np.isfinite([ours, raw]).all() and ours > 0 and raw > 0
        assert row["ratio ours/raw"] == pytest.approx(ours / raw, rel=1e-12)
        assert table["ratios"][f"{row['scene']}: SimCore / raw mj_step"] == pytest.approx(ours / raw, rel=1e-12)
        assert row["real-time factor (ours)"] == pytest.approx(ours * 0.05, rel=1e-12)  # 20 Hz control
        assert row["physics steps per control step"] == 25  # 2 ms physics
    assert table["code"]["git_commit"]


def test_unknown_benchmark_is_a_one_line_error(capsys):
    code, _, stderr = in_process(capsys, "bench", "nope")
    assert code == 1
    assert stderr.strip().count("\n") == 0 and "unknown benchmark 'nope'" in stderr


def test_output_into_a_closed_pipe_stops_quietly(tmp_path):
    """`hingelab datasets info X | head -1`: the reader leaves early; no traceback, exit 141. (The dataset is
    made in this process: only the command under test pays a process start.)"""
    from hingelab.cli.main import main

    data = tmp_path / "clouds"
    assert main(["generate", "clouds", "--n", "40", "--per-episode", "20", "--out", str(data), "--no-progress"]) == 0
    proc = subprocess.Popen([sys.executable, "-m", "hingelab.cli.main", "datasets", "info", str(data)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # nobody reads: the first flush fails with a broken pipe
    _, err = proc.communicate(timeout=120)
    assert b"Traceback" not in err and b"BrokenPipe" not in err, err.decode()
    assert proc.returncode == 141

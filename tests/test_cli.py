"""The ``hingelab`` command as a user runs it: a real subprocess, checked output."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest


def hingelab(*args, check=True):
    return subprocess.run([sys.executable, "-m", "hingelab.cli.main", *args], capture_output=True, text=True,
                          check=check, timeout=300)


def test_help_lists_the_commands():
    out = hingelab("--help").stdout
    for verb in ("demo", "bench", "datasets"):
        assert verb in out


def test_demo_runs_and_measures_the_platform(tmp_path):
    out_file = tmp_path / "demo.json"
    result = hingelab("demo", "--out", str(out_file))
    assert "lifted it" in result.stdout and "demo finished" in result.stdout
    measured = json.loads(out_file.read_text())["step_platform"]
    assert measured["hold_drift_mm"] < 5
    assert measured["finger_hinge_range_rad"][1] - measured["finger_hinge_range_rad"][0] > 0.15
    assert measured["reach_worst_error_mm"] < 2 and not measured["reach_table_collision"]
    assert measured["lift_cm"] > 4.5
    low = json.loads(out_file.read_text())["step_low_level_policy"]  # the shipped low-level policy
    assert len(low["tip_gap_error_mm"]) == 3 and 0 <= low["settled_success_rate"] <= 1
    assert "low_level_experts.json: settled success" in result.stdout


def test_bench_sim_writes_its_table(tmp_path):
    result = hingelab("bench", "sim", "--quick", "--out", str(tmp_path))
    assert "SimCore / raw mj_step" in result.stdout
    table = json.loads((tmp_path / "sim.json").read_text())
    assert {row["scene"] for row in table["rows"]} == {"tool_shape", "tool_pick"}
    for ratio in table["ratios"].values():
        assert 0 < ratio < 5
    assert table["code"]["git_commit"]


def test_unknown_benchmark_is_a_one_line_error():
    result = hingelab("bench", "nope", check=False)
    assert result.returncode == 1
    assert result.stderr.strip().count("\n") == 0 and "unknown benchmark 'nope'" in result.stderr


def test_output_into_a_closed_pipe_stops_quietly(tmp_path):
    """`hingelab datasets info X | head -1`: the reader leaves early; no traceback, exit 141."""
    data = tmp_path / "clouds"
    hingelab("generate", "clouds", "--n", "40", "--per-episode", "20", "--out", str(data), "--no-progress")
    proc = subprocess.Popen([sys.executable, "-m", "hingelab.cli.main", "datasets", "info", str(data)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # nobody reads: the first flush fails with a broken pipe
    _, err = proc.communicate(timeout=120)
    assert b"Traceback" not in err and b"BrokenPipe" not in err, err.decode()
    assert proc.returncode == 141

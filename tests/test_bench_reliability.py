"""``hingelab bench reliability``: its probes run as real processes and its table counts what they find.

One bench run over a few fast probes of the real list and deliberately broken ones (a traceback, a write
beside ``--out``, a duplicated episode, a refusal that writes into ``--out``, a probe that cannot run, a
probe whose own code fails): the real ones pass, each broken one is counted as what it is, so the bench
can fail. The full list is run by hand into ``analysis/reliability/`` (its README)."""

from __future__ import annotations

import json
import sys
import textwrap

import pytest

from hingelab.bench import reliability, table_dir
from hingelab.bench.probe_runner import ProbeRun
from hingelab.bench.reliability import Probe
from hingelab.paths import ANALYSIS_DIR

REAL = ["crafted episode id ../../x: export ros2, verify", "--seed -1: generate heuristic",
        "--out a file: generate clouds", "dangling .mcap symlink and a symlink loop: verify, info, index, report"]


def _python(s: ProbeRun, code: str, expect=(0,)):
    return s.wait(s.start_process([sys.executable, "-c", textwrap.dedent(code)], f"python -c {code[:20]!r}", expect))


def _traceback(s: ProbeRun) -> None:
    _python(s, "raise RuntimeError('a bug')", expect=(1,))


def _write_beside_out(s: ProbeRun) -> None:
    _python(s, "import pathlib; pathlib.Path('decoy/stray.txt').write_text('x')")


def _duplicate_an_episode(s: ProbeRun) -> None:
    _python(s, """
        from hingelab.episodes import create_dataset
        from hingelab.episodes.synthetic import write_synthetic_episode
        create_dataset('out', name='out', source='synthetic', seed=0, config={})
        for seed in (0, 0):
            write_synthetic_episode('out', seed, n_steps=3)
    """)
    s.expect_episodes(s.out, expected=2)


def _refuse_but_write_into_out(s: ProbeRun) -> None:
    _python(s, "import os, sys; os.mkdir('out'); sys.exit('hingelab: error: refused')", expect=(1,))


def _cannot_run(s: ProbeRun) -> None:
    s.give_up("nothing to try here")


def _broken_probe_code(s: ProbeRun) -> None:
    raise ValueError("a mistake in the probe")


BROKEN = [Probe("broken: a traceback", _traceback), Probe("broken: a write beside --out", _write_beside_out),
          Probe("broken: a duplicated episode", _duplicate_an_episode),
          Probe("broken: a refusal that writes into --out", _refuse_but_write_into_out),
          Probe("broken: cannot run", _cannot_run), Probe("broken: the probe's own code fails", _broken_probe_code)]


@pytest.fixture(scope="module")
def bench():
    probes = [p for p in reliability.PROBES if p.name in REAL]
    assert [p.name for p in probes] == REAL
    return reliability.run(probes=probes + BROKEN, progress=False)


def test_the_table_lists_every_probe_with_its_outcome_and_totals(bench, tmp_path):
    rows = {row["probe"]: row for row in bench.rows}
    assert list(rows) == REAL + [p.name for p in BROKEN]
    assert all(set(reliability.COLUMNS) <= set(row) for row in bench.rows)
    md_path, json_path = bench.write(tmp_path)
    assert (md_path.name, json_path.name) == ("reliability.md", "reliability.json")
    text = md_path.read_text()
    assert "| probe | commands | exit | tracebacks | writes outside --out |" in text
    assert "Totals: probes 10, probes run 8, not run 2, failed 4, " in text
    doc = json.loads(json_path.read_text())
    assert doc["totals"] == bench.totals and doc["code"]["git_commit"] and len(doc["rows"]) == 10
    assert table_dir("reliability") == ANALYSIS_DIR / "reliability"


def test_the_real_probes_pass_refused_in_one_line_with_nothing_written(bench):
    for row in bench.rows[:len(REAL)]:
        assert row["outcome"] == "pass", row
        assert row["tracebacks"] == 0 and row["writes outside --out"] == 0, row
        assert "hingelab" in row["detail"] and "error:" in row["detail"], row
    crafted = bench.rows[0]
    assert crafted["commands"].startswith("hingelab datasets export a/b/c/crafted --format ros2 --out a/b/c/out")
    assert crafted["exit"] == "1, 1" and "episode_id" in crafted["detail"]
    assert bench.rows[1]["exit"] == "2" and "[0, 2**32)" in bench.rows[1]["detail"]


def test_each_broken_probe_is_counted_as_what_it_did(bench):
    rows = {row["probe"]: row for row in bench.rows}
    traceback = rows["broken: a traceback"]
    assert traceback["outcome"] == "FAIL" and traceback["tracebacks"] == 1
    stray = rows["broken: a write beside --out"]
    assert stray["outcome"] == "FAIL" and stray["writes outside --out"] == 1
    assert stray["outside_write_paths"] == ["PROBE/work/decoy/stray.txt"]
    duplicated = rows["broken: a duplicated episode"]
    assert duplicated["outcome"] == "FAIL" and (duplicated["episodes expected"], duplicated["episodes found"],
                                               duplicated["duplicated"], duplicated["lost"]) == (2, 2, 1, 1)
    refused = rows["broken: a refusal that writes into --out"]
    assert refused["outcome"] == "FAIL" and "refused, yet --out changed" in refused["detail"]
    for name, reason in (("broken: cannot run", "nothing to try here"),
                         ("broken: the probe's own code fails", "ValueError: a mistake in the probe")):
        assert rows[name]["outcome"] == "not run" and reason in rows[name]["detail"]  # never passed
    assert {k: bench.totals[k] for k in ("tracebacks", "writes outside --out", "duplicated episodes",
                                         "lost episodes", "failed")} == {
        "tracebacks": 1, "writes outside --out": 1, "duplicated episodes": 1, "lost episodes": 1, "failed": 4}
    assert reliability.verdict(bench).startswith("4 of 8 reliability probes failed (tracebacks 1, ")


def test_the_command_writes_its_table_and_fails_when_a_probe_does(tmp_path, monkeypatch, capsys):
    from hingelab.cli.main import main

    seed_probe = next(p for p in reliability.PROBES if p.name == "--seed 4294967296: train low")
    monkeypatch.setattr(reliability, "PROBES", [seed_probe])
    assert main(["bench", "reliability", "--quick", "--out", str(tmp_path / "ok")]) == 0
    assert "Totals: probes 1, probes run 1, not run 0, failed 0, " in (tmp_path / "ok" / "reliability.md").read_text()
    capsys.readouterr()
    monkeypatch.setattr(reliability, "PROBES", [Probe("broken: a traceback", _traceback, quick=True)])
    assert main(["bench", "reliability", "--quick", "--out", str(tmp_path / "bad")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("hingelab: error: 1 of 1 reliability probes failed (tracebacks 1")
    assert (tmp_path / "bad" / "reliability.json").is_file()  # the table is written all the same

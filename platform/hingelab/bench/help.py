"""``hingelab bench help``: the wall time of ``hingelab [COMMAND] --help``, each a fresh process, as a user types it.

The target (issue 45) is under 0.5 s for every command. Each line is run ``REPEATS`` times, interleaved with the
references, and its median kept: the bare interpreter start (``python -c pass``) and the start plus ``import numpy``
(what importing gymnasium, which ``import hingelab`` registers the envs with, costs at least). Every line runs once
unmeasured first, and with Python's compiled-module cache on (``PYTHONDONTWRITEBYTECODE`` dropped), as on a
user's machine. The load average before and after is in the notes: on a busy machine every figure grows, the
references with them.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import time

from hingelab.bench.table import BenchTable

MEASURES = ("platform/hingelab/cli", "platform/hingelab/__init__.py", "platform/hingelab/tasks.py",
            "platform/hingelab/out_dir.py", "platform/hingelab/arguments.py", "platform/hingelab/errors.py")
TARGET_S = 0.5
REPEATS = 5
HELP_LINES = ([], ["generate", "heuristic"], ["generate", "clouds"], ["train", "low"], ["train", "high"],
              ["train", "high", "--learner", "residual-sac"], ["train", "flat"], ["train", "encoder"], ["eval", "high"],
              ["eval", "low"], ["trial"], ["sweep"], ["reproduce"], ["report"], ["view"], ["diagnose", "noise"],
              ["datasets", "export"], ["datasets", "import-ros2"], ["bench"], ["demo"])
REFERENCES = {"python -c pass (the interpreter's start)": [sys.executable, "-c", "pass"],
              "python -c 'import numpy'": [sys.executable, "-c", "import numpy"]}


# as a user's shell has it: Python keeps compiled modules (__pycache__, git-ignored); a machine that sets
# PYTHONDONTWRITEBYTECODE (this one does) compiles every hingelab module on every start instead (~0.1 s)
ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def _seconds(argv: list[str]) -> float:
    start = time.perf_counter()
    done = subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, timeout=120, env=ENV)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} exited {done.returncode}: {done.stderr.strip()[-300:]}")
    return seconds


def _hingelab(words: list[str]) -> list[str]:
    return [sys.executable, "-m", "hingelab.cli.main", *words, "--help"]


def run(quick: bool = False) -> BenchTable:
    repeats = 1 if quick else REPEATS
    lines = HELP_LINES[:3] if quick else HELP_LINES
    commands = {**REFERENCES, **{" ".join(["hingelab", *words, "--help"]): _hingelab(words) for words in lines}}
    for argv in commands.values():  # once unmeasured: the compiled modules written, the files in the page cache
        _seconds(argv)
    load_before = os.getloadavg()[0]
    times: dict[str, list[float]] = {name: [] for name in commands}
    for _ in range(repeats):  # interleaved: a busy spell of the shared machine hits every line alike
        for name, argv in commands.items():
            times[name].append(_seconds(argv))
    load_after = os.getloadavg()[0]
    def verdict(name: str, median: float) -> str:
        return "reference" if name in REFERENCES else ("yes" if median < TARGET_S else "no")

    rows = [{"command": name, "median_s": statistics.median(t), "max_s": max(t), "runs": len(t),
             "under_target": verdict(name, statistics.median(t))} for name, t in times.items()]
    ours = [r for r in rows if r["command"] not in REFERENCES]
    start = statistics.median(times[next(iter(REFERENCES))])
    return BenchTable(
        name="help",
        title=f"Help: wall time of hingelab [COMMAND] --help, a fresh process each (target < {TARGET_S} s)",
        columns=["command", "median_s", "max_s", "runs", "under_target"], rows=rows,
        ratios={"slowest help / the interpreter's start": max(r["median_s"] for r in ours) / start,
                "median help / the interpreter's start": statistics.median(r["median_s"] for r in ours) / start},
        totals={"commands": len(ours), "under the target": sum(r["under_target"] == "yes" for r in ours),
                "slowest median s": max(r["median_s"] for r in ours)},
        notes=[f"load average (1 min) {load_before:.2f} before, {load_after:.2f} after, on {os.cpu_count()} cores"],
        config={"quick": quick, "repeats": repeats, "target_s": TARGET_S})


__all__ = ["run", "MEASURES", "HELP_LINES", "TARGET_S"]

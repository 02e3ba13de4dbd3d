"""Benchmarks: ``hingelab bench NAME`` runs ``hingelab.bench.NAME.run()``.

Each benchmark measures ours against a named baseline in one run and writes
``analysis/bench/NAME.md`` and ``.json`` through ``BenchTable.write``; a benchmark with a folder of
its own in ``TABLE_FOLDERS`` (``reliability``: probes with outcomes, no baseline) writes there.

Each benchmark's module also declares ``MEASURES``: the repository paths (files or folders)
of the code and models its figures depend on. A committed table is stale once a commit after
the one it records changes any of them (``hingelab.bench.freshness``); ``hingelab bench --stale``
lists the stale tables and the command that regenerates each.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from hingelab.paths import ANALYSIS_DIR, REPO_ROOT

# name -> module; a benchmark's module exposes run(quick: bool) -> BenchTable and MEASURES
BENCHMARKS = {
    "sim": "hingelab.bench.sim",
    "datasets": "hingelab.bench.datasets",
    "perception": "hingelab.bench.perception",
    "envs": "hingelab.bench.envs",
    "train": "hingelab.bench.train",
    "sac": "hingelab.bench.sac",
    "ensemble": "hingelab.bench.ensemble",
    "cluster": "hingelab.bench.cluster",
    "reliability": "hingelab.bench.reliability",
    "help": "hingelab.bench.help",
}

# name -> its tables' folder under analysis/, where it is not bench/ (written there, and looked for by --stale)
TABLE_FOLDERS = {"reliability": "reliability"}

# measured by every benchmark: the locked package versions (torch, MuJoCo, numba, SB3, ...)
COMMON_MEASURES = ("constraints.txt",)


def table_dir(name: str) -> Path:
    """The folder of benchmark ``name``'s committed tables ``NAME.md`` and ``NAME.json``."""
    return ANALYSIS_DIR / TABLE_FOLDERS.get(name, "bench")


def measured_paths(name: str) -> tuple[str, ...]:
    """Repository paths whose changes make benchmark ``name``'s table stale.

    The module's ``MEASURES``, the module itself and ``COMMON_MEASURES``.
    """
    module = importlib.import_module(BENCHMARKS[name])
    own = Path(module.__file__).resolve().relative_to(REPO_ROOT).as_posix()
    return (*module.MEASURES, own, *COMMON_MEASURES)

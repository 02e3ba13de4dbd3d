"""Benchmarks: ``hingelab bench NAME`` runs ``hingelab.bench.NAME.run()``.

Each benchmark measures ours against a named baseline in one run and writes
``analysis/bench/NAME.md`` and ``.json`` through ``write_bench``.
"""

# name -> module; a benchmark's module exposes run(quick: bool) -> BenchTable
BENCHMARKS = {
    "sim": "hingelab.bench.sim",
    "datasets": "hingelab.bench.datasets",
    "perception": "hingelab.bench.perception",
    "envs": "hingelab.bench.envs",
    "train": "hingelab.bench.train",
}

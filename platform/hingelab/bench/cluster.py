"""``hingelab bench cluster``: rollout episodes as Ray tasks against local worker processes, and Ray's costs.

Two workloads, each run by the same episode runner in both arms (its env and policy built once per
worker, every episode writing its MCAP file into a fresh dataset folder):

- evaluation: ``eval low`` episodes of the shipped low-level policy on ToolShape-v0
  (``eval_on_ray.LowLevelEpisodes``, what ``hingelab eval low --ray`` runs);
- generation: privileged heuristic demos on ToolPick-v0 (``rollout.HeuristicEpisodes``, what
  ``hingelab generate heuristic --ray`` runs).

Arms, on the same cores (``WORKERS``): ours, one Ray task per episode on a local one-node Ray of
``WORKERS`` CPUs (``fan_out``); the baseline, a ``multiprocessing`` spawn pool of ``WORKERS``
processes (what ``--workers`` uses). The rate is the steady one: episodes per second between the
first ``WORKERS`` results (the workers' start-up: imports, env, policy) and the last; start-up is
given apart. Then Ray's own costs: ``ray.init`` of a local Ray, the per-task overhead of empty
tasks (submitted together, and one at a time), and the write rate an episode puts on storage
(MB per episode, MB/s per worker), the figure that bounds a cluster on shared storage.
"""

from __future__ import annotations

import functools
import multiprocessing as mp
import shutil
import tempfile
import time
from pathlib import Path

from hingelab.bench.table import BenchTable
from hingelab.envs.low_level import PolicyLowLevel
from hingelab.episodes import create_dataset
from hingelab.policies.low_level import SHIPPED_LOW_LEVEL
from hingelab.rollouts.heuristic_demos import HeuristicEpisodes, HeuristicRunConfig
from hingelab.rollouts.low_level import evaluation_env_arguments, make_eval_env, sampled_goals
from hingelab.rollouts.on_ray import LowLevelEpisodes
from hingelab.seeds import demo_seed
from hingelab.workers.ray_fan_out import fan_out
from hingelab.workers.ray_runtime import ray_session

# the code this benchmark measures (the bench's own module is added by hingelab.bench.measured_paths)
MEASURES = ("platform/hingelab/workers", "platform/hingelab/rollouts/on_ray.py",
            "platform/hingelab/rollouts/low_level.py", "platform/hingelab/policies/low_level.py",
            "platform/hingelab/heuristic", "platform/hingelab/rollouts/heuristic_demos.py", "platform/hingelab/envs",
            "platform/hingelab/episodes", "platform/hingelab/seeds.py")

WORKERS = 2
ROUNDS = 3

_POOL_RUNNER: dict = {}


def _pool_init(factory) -> None:
    _POOL_RUNNER["runner"] = factory()


def _pool_run(item):
    return _POOL_RUNNER["runner"](item)


def _steady_rate(stamps: list[float], start: float, workers: int) -> tuple[float, float]:
    """(episodes/s after the first ``workers`` results, seconds to the first result)."""
    stamps = sorted(stamps)
    first = stamps[workers - 1] if len(stamps) > workers else stamps[0]
    later = [s for s in stamps if s > first]
    rate = len(later) / (stamps[-1] - first) if later else float("nan")
    return rate, stamps[0] - start


def _pool_arm(factory, items) -> tuple[float, float]:
    start = time.perf_counter()
    stamps = []
    with mp.get_context("spawn").Pool(WORKERS, initializer=_pool_init, initargs=(factory,)) as pool:
        for _ in pool.imap_unordered(_pool_run, items):
            stamps.append(time.perf_counter())
    return _steady_rate(stamps, start, WORKERS)


def _ray_arm(factory, items) -> tuple[float, float]:
    start = time.perf_counter()
    stamps = []
    fan_out(factory, items, on_result=lambda _: stamps.append(time.perf_counter()), progress=False)
    return _steady_rate(stamps, start, WORKERS)


def _noop(x):
    return x


def _ray_overheads(ray, tasks: int) -> dict:
    task = ray.remote(num_cpus=1)(_noop)
    ray.get([task.remote(0) for _ in range(20)])  # workers up
    start = time.perf_counter()
    ray.get([task.remote(i) for i in range(tasks)])
    batched_ms = 1000 * (time.perf_counter() - start) / tasks
    start = time.perf_counter()
    for i in range(tasks // 10):
        ray.get(task.remote(i))
    serial_ms = 1000 * (time.perf_counter() - start) / (tasks // 10)
    return {"batched_ms": batched_ms, "serial_ms": serial_ms}


def _workloads(root: Path, quick: bool):
    env_args = {**evaluation_env_arguments(PolicyLowLevel(SHIPPED_LOW_LEVEL).model), "randomize": True}
    env = make_eval_env(env_args)
    goals = sampled_goals(env.unwrapped.calibration, env.unwrapped.reachable_range, 8 if quick else 40, seed=0)
    env.close()
    config = HeuristicRunConfig(episodes=4 if quick else 12, seed=0, workers=WORKERS)
    seeds = [demo_seed(0, k) for k in range(config.episodes)]

    def evaluation(folder: Path):
        create_dataset(folder, name=folder.name, source="low_level_evaluation", seed=0, config={})
        return functools.partial(LowLevelEpisodes, env_args, str(folder), str(SHIPPED_LOW_LEVEL), None), goals

    def generation(folder: Path):
        create_dataset(folder, name=folder.name, source="heuristic", seed=0, config={})
        return functools.partial(HeuristicEpisodes, config, str(folder)), seeds

    return {"evaluation (eval low, shipped policy, ToolShape-v0)": evaluation,
            "generation (heuristic demos, ToolPick-v0)": generation}


def _episode_bytes(folder: Path) -> tuple[float, int]:
    files = list((folder / "episodes").glob("*.mcap"))
    return sum(f.stat().st_size for f in files) / max(len(files), 1), len(files)


def run(quick: bool = False) -> BenchTable:
    root = Path(tempfile.mkdtemp(prefix="hingelab_bench_cluster_"))
    rows, ratios, notes = [], {}, []
    try:
        workloads = _workloads(root, quick)
        results = {name: {"pool": [], "ray": []} for name in workloads}
        rounds = 1 if quick else ROUNDS
        start = time.perf_counter()
        with ray_session(None, WORKERS) as ray:
            init_s = time.perf_counter() - start
            for round_ in range(rounds):  # interleaved: a slower spell of the shared host hits both arms
                for k, (name, make) in enumerate(workloads.items()):
                    factory, items = make(root / f"{round_}_{k}_pool")
                    results[name]["pool"].append(_pool_arm(factory, items))
                    folder = root / f"{round_}_{k}_ray"
                    factory, items = make(folder)
                    results[name]["ray"].append(_ray_arm(factory, items))
                    results[name]["bytes"], results[name]["episodes"] = _episode_bytes(folder)
            overheads = _ray_overheads(ray, 200 if quick else 2000)
        for name, r in results.items():
            # the best round of each arm (its rate and that round's start-up)
            pool_rate, pool_first = max(r["pool"], key=lambda x: x[0])
            ray_rate, ray_first = max(r["ray"], key=lambda x: x[0])
            mb = r["bytes"] / 1e6
            rows.append({"workload": name, "episodes": r["episodes"], "local workers (episodes/s)": pool_rate,
                         "Ray tasks (episodes/s)": ray_rate, "Ray / local workers": ray_rate / pool_rate,
                         "first episode, local (s)": pool_first, "first episode, Ray (s)": ray_first,
                         "MB per episode": mb, "MB/s per worker": mb * ray_rate / WORKERS,
                         f"MB/s at {WORKERS} workers": mb * ray_rate})
            ratios[f"{name.split(' (')[0]}: Ray tasks / local worker processes"] = ray_rate / pool_rate
        notes += [
            f"{WORKERS} workers in both arms: a local one-node Ray of {WORKERS} CPUs (one task per episode, 1 CPU "
            f"each; hingelab.workers.ray_fan_out) against a multiprocessing spawn pool of {WORKERS} processes, the "
            "same episode runner (env and policy built once per worker) writing MCAP into a fresh dataset folder.",
            f"Rates are steady: episodes per second after the first {WORKERS} results (the workers' start-up) to the "
            f"last, the best of {rounds} interleaved rounds per arm (pool, then Ray, per workload and round); 'first "
            "episode' is the start-up as a user waits for it (the pool's from new processes; Ray's without ray.init, "
            "and on worker processes that an earlier workload or round started, already past their imports).",
            "Ray starts its workers with OMP_NUM_THREADS set to the task's CPUs (1); the spawn pool's processes "
            "inherit the shell's (unset), as hingelab's --workers do: part of any difference in the ratio.",
            f"Ray's costs: ray.init of a local Ray {init_s:.2f} s; an empty task {overheads['batched_ms']:.2f} ms "
            f"when submitted together (throughput), {overheads['serial_ms']:.2f} ms one at a time (round trip).",
            "MB/s per worker = MB per episode x the Ray arm's episodes/s / workers: what each core adds to the "
            "shared storage's write load.",
        ]
    finally:
        shutil.rmtree(root, ignore_errors=True)
    return BenchTable(
        name="cluster",
        title="Rollouts on Ray: episodes per second as Ray tasks vs local worker processes on the same cores",
        columns=list(rows[0].keys()), rows=rows, ratios=ratios, notes=notes,
        config={"quick": quick, "workers": WORKERS, "ray_init_s": init_s,
                "ray_task_overhead_ms_batched": overheads["batched_ms"],
                "ray_task_overhead_ms_serial": overheads["serial_ms"]})

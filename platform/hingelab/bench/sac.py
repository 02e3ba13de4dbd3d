"""``hingelab bench sac``: SAC gradient updates per second, hingelab's FastSAC vs bare SB3 SAC.

The update alone, on the low-level task's shapes: ``MultiInputPolicy``, Dict observations
(``observation`` 26, ``achieved_goal`` 2, ``desired_goal`` 2), a 9-D action, actor and twin
critics 2 x 256 ReLU, batch 256, ``ent_coef="auto"``, a ``DictReplayBuffer`` full of random
transitions. Up to five arms, each in its own process (so that process-wide settings, such as
glibc's heap, differ between them):

- ``SB3 SAC``: ``stable_baselines3.SAC`` as it comes: the baseline;
- ``SB3 SAC + configure_torch``: the same with hingelab's process settings, which separates
  them from FastSAC's own changes;
- ``FastSAC + configure_torch``: ``hingelab.learners.sac.fast_sac``, what ``hingelab train low``
  uses: ours;
- ``FastSAC compiled + configure_torch``: the same with ``update="compiled"``, each gradient step
  one ``torch.compile``d function (``hingelab.learners.sac.compiled_update``; its compilation is
  part of the untimed warm-up);
- ``FastSAC fused + configure_torch``: the same with ``update="fused"``, the gradients written out
  by hand into buffers made once (``hingelab.learners.sac.fused_update``; no compilation);
- ``matmuls of one update``: a diagnostic, not an update: the fused update's matrix products
  alone (the same shapes and layouts, one after another, into buffers made once). At this
  machine's matrix-product rate it is the least time any torch update of this algorithm can
  take, so its ratio to SBX says whether the target (>= SBX) is reachable here at all;
- ``SBX SAC``: the JAX SAC of ``sbx-rl`` (the bench extra), its update jitted by XLA, on one
  XLA thread (``XLA_FLAGS`` set in its process before JAX loads): the compiled baseline. Only at
  1 thread, and only when ``sbx`` is installed; without it the bench says so and runs the others.

In each round every arm runs one block of updates, one arm at a time, in an order shuffled per
round (a slower spell of the shared machine hits all arms alike); an arm's figure is its median
block rate, the ratio is ours / baseline of those medians, at 1 torch thread (the headline, what
training uses) and, in the full run, at 2. Then a cProfile breakdown of one update by part, at 1
thread. Why each change is faster, and what each bought alone (an ablation), is written up in
``analysis/bench/history/sac_updates.md``.
"""

from __future__ import annotations

import cProfile
import importlib.util
import multiprocessing as mp
import os
import pstats
import statistics
import time
import traceback
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import stable_baselines3
import torch
import torch as th
from gymnasium import spaces
from stable_baselines3 import SAC
from stable_baselines3.common.logger import configure
from tqdm import tqdm

from hingelab.bench.table import BenchTable
from hingelab.learners.sac.fast_sac import FastSAC, configure_torch

# the code this benchmark measures (the bench's own module is added by hingelab.bench.measured_paths)
MEASURES = ("platform/hingelab/learners/sac/fast_sac.py", "platform/hingelab/learners/sac/compiled_update.py",
            "platform/hingelab/learners/sac/fused_update.py")

SEED = 0
BATCH_SIZE = 256
BUFFER_SIZE = 100_000
WARMUP_UPDATES = 20  # untimed, in every worker, before its first block at a thread setting

BASELINE = "SB3 SAC"
OURS = "FastSAC + configure_torch"
#: arm -> (role, algorithm, hingelab's process settings)
ARMS: dict[str, tuple[str, str, bool]] = {
    BASELINE: ("baseline", "SAC", False),
    "SB3 SAC + configure_torch": ("baseline + our process settings", "SAC", True),
    OURS: ("ours", "FastSAC", True),
}
COMPILED = "FastSAC compiled + configure_torch"
FUSED = "FastSAC fused + configure_torch"
MATMULS = "matmuls of one update"
SBX = "SBX SAC"
#: arms beyond the three above: arm -> (role, algorithm, hingelab's process settings, thread settings (None: all))
EXTRA_ARMS: dict[str, tuple[str, str, bool, tuple[int, ...] | None]] = {
    COMPILED: ("ours, compiled update", "FastSAC-compiled", True, None),
    FUSED: ("ours, update by hand", "FastSAC-fused", True, None),
    MATMULS: ("diagnostic: the fused update's matrix products alone", "matmuls", True, (1,)),
    SBX: ("compiled baseline (JAX, XLA)", "SBX", False, (1,)),
}
#: one XLA thread (set before JAX loads): SBX's rate "on one core", as the torch arms' 1 thread
SBX_XLA_FLAGS = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
UNEVEN_BLOCKS = 2.0  # an arm whose fastest block is this many times its slowest: a busy machine, flagged
COLUMNS = ["threads", "config", "role", "updates/s", "min", "max", "ms/update", "/ SB3 SAC"]


# --- the model under test ------------------------------------------------------------------


def dummy_goal_env() -> Any:
    """An env with the spaces of the goal-conditioned low-level task; steps return random data."""
    class DummyGoalEnv(gym.Env):
        observation_space = spaces.Dict(
            {
                "observation": spaces.Box(-10.0, 10.0, (26,), np.float32),
                "achieved_goal": spaces.Box(-1.0, 1.0, (2,), np.float32),
                "desired_goal": spaces.Box(-1.0, 1.0, (2,), np.float32),
            }
        )
        action_space = spaces.Box(-1.0, 1.0, (9,), np.float32)

        def reset(self, *, seed: int | None = None, options: dict | None = None) -> Any:
            super().reset(seed=seed)
            return self.observation_space.sample(), {}

        def step(self, action: np.ndarray) -> Any:
            return self.observation_space.sample(), 0.0, False, False, {}

    return DummyGoalEnv()


def make_filled_model(cls: type, seed: int = SEED, buffer_size: int = BUFFER_SIZE, batch_size: int = BATCH_SIZE,
                      noise_seed: int | None = None, done_rate: float = 0.02, **kwargs: Any) -> Any:
    """SAC or FastSAC, MultiInputPolicy, 2 x 256, batch 256, on the dummy goal env, buffer full of noise
    (drawn from ``noise_seed``, default ``seed``; a ``done_rate`` share of terminal transitions)."""
    policy_kwargs = dict(kwargs.pop("policy_kwargs", None) or {})
    policy_kwargs.setdefault("net_arch", [256, 256])
    model = cls("MultiInputPolicy", dummy_goal_env(), batch_size=batch_size, buffer_size=buffer_size,
                learning_starts=0, seed=seed, device="cpu", policy_kwargs=policy_kwargs, **kwargs)
    rb = model.replay_buffer
    rng = np.random.default_rng(seed if noise_seed is None else noise_seed)
    for key in rb.observations:
        rb.observations[key][:] = rng.standard_normal(rb.observations[key].shape)
        rb.next_observations[key][:] = rng.standard_normal(rb.next_observations[key].shape)
    rb.actions[:] = rng.uniform(-1.0, 1.0, rb.actions.shape)
    rb.rewards[:] = rng.standard_normal(rb.rewards.shape)
    rb.dones[:] = rng.random(rb.dones.shape) < done_rate
    rb.full, rb.pos = True, 0
    model.set_logger(configure(None, []))
    return model


def update_rate(model: Any, n_updates: int, batch_size: int = BATCH_SIZE,
                clock: Callable[[], float] = time.perf_counter) -> float:
    """Gradient updates per second of ``model.train(gradient_steps=n_updates, batch_size=...)``.

    The replay buffer must already hold data. Wall time: measure the arms interleaved.
    """
    start = clock()
    model.train(gradient_steps=n_updates, batch_size=batch_size)
    return n_updates / (clock() - start)


class UpdateMatmuls:
    """The matrix products of one fused SAC update on the bench's shapes (``train`` runs them, as a model's
    ``train`` runs updates): actor 2 x 256 on 2B rows, n critics 2 x 256 as stacks; the products of the
    target (``target_critics`` members, default all: SAC's minimum; REDQ computes a pair), the critic loss and
    its backward, the actor loss through the critics and the actor's backward. Operands and outputs are made
    once, as the fused update's buffers are; ``flops`` counts them."""

    def __init__(self, batch: int = BATCH_SIZE, obs_dim: int = 30, action_dim: int = 9, hidden: int = 256,
                 critics: int = 2, target_critics: int | None = None):
        b, d, a, h, n = batch, obs_dim, action_dim, hidden, critics
        m = critics if target_critics is None else target_critics  # the members the bootstrap target computes
        r = lambda *shape: th.randn(shape)  # noqa: E731

        def critic_forward(k: int) -> list:
            return [(r(k, b, d + a), r(k, h, d + a).transpose(1, 2)), (r(k, b, h), r(k, h, h).transpose(1, 2)),
                    (r(k, b, h), r(k, 1, h).transpose(1, 2))]

        actor_products = [(r(2 * b, d), r(h, d).t()), (r(2 * b, h), r(h, h).t()), (r(2 * b, h), r(2 * a, h).t())]
        critic_backward = [(r(n, b, 1).transpose(1, 2), r(n, b, h)), (r(n, b, 1), r(n, 1, h)),
                           (r(n, b, h).transpose(1, 2), r(n, b, h)), (r(n, b, h), r(n, h, h)),
                           (r(n, b, h).transpose(1, 2), r(n, b, d + a))]
        actor_loss_backward = [(r(n, b, 1), r(n, 1, h)), (r(n, b, h), r(n, h, h)), (r(n, b, h), r(n, h, a))]
        actor_backward = [(r(b, 2 * a).t(), r(b, h)), (r(b, 2 * a), r(2 * a, h)), (r(b, h).t(), r(b, h)),
                          (r(b, h), r(h, h)), (r(b, h).t(), r(b, d))]
        critic_forward_all = critic_forward(m) + critic_forward(n) * 2  # the target; the fit; the actor's loss
        products = [*actor_products, *critic_forward_all, *critic_backward, *actor_loss_backward, *actor_backward]
        self.products = [(x, y, th.empty(*x.shape[:-1], y.shape[-1])) for x, y in products]
        self.flops = sum(2 * x.shape[-2] * x.shape[-1] * y.shape[-1] * (x.shape[0] if x.dim() == 3 else 1)
                         for x, y, _ in self.products)

    def train(self, gradient_steps: int, batch_size: int = BATCH_SIZE) -> None:
        for _ in range(gradient_steps):
            for x, y, out in self.products:
                (th.bmm if x.dim() == 3 else th.mm)(x, y, out=out)


# --- where one update goes -------------------------------------------------------------------

# (part, alternatives): the first alternative present in the profile is used, so that a FastSAC
# function and the SB3 function it may fall back to are not counted twice.
_PROFILE_PARTS: list[tuple[str, list[list[tuple[str, str]]]]] = [
    ("replay sampling + to-tensor", [[("fast_sac.py", "_sample")], [("buffers.py", "sample")]]),
    ("actor forward (obs + next_obs, with squashed Gaussian)",
     [[("fast_sac.py", "_action_log_prob")], [("sac/policies.py", "action_log_prob")]]),
    ("critic forward (target + critic loss + actor loss)",
     [[("fast_sac.py", "_q_values"), ("fast_sac.py", "_critic_features")], [("common/policies.py", "forward")]]),
    ("backward (3 losses)", [[("torch/_tensor.py", "backward")]]),
    ("Adam step (3 optimizers)", [[("torch/optim/optimizer.py", "wrapper")]]),
    ("zero_grad", [[("torch/optim/optimizer.py", "zero_grad")]]),
    ("polyak update", [[("fast_sac.py", "_polyak")], [("common/utils.py", "polyak_update")]]),
    (".item() syncs", [[("~", "<method 'item' of 'torch._C.TensorBase' objects>")]]),
    ("logger.record", [[("logger.py", "record")]]),
]
REST = "rest (loss arithmetic, ent_coef, Python)"
PROFILE_TOTAL = "total under cProfile"


def profile_breakdown(model: Any, n_updates: int, batch_size: int = BATCH_SIZE) -> dict[str, float]:
    """ms per update by part, from cProfile (which inflates the Python-heavy parts a little)."""
    model.train(gradient_steps=WARMUP_UPDATES, batch_size=batch_size)
    profiler = cProfile.Profile()
    start = time.perf_counter()
    profiler.enable()
    model.train(gradient_steps=n_updates, batch_size=batch_size)
    profiler.disable()
    total = time.perf_counter() - start
    stats = pstats.Stats(profiler).stats  # type: ignore[attr-defined]
    cumulative: dict[tuple[str, str], float] = {}
    for (filename, _line, func), (_cc, _nc, _tt, ct, _callers) in stats.items():
        for _part, alternatives in _PROFILE_PARTS:
            for alternative in alternatives:
                for suffix, name in alternative:
                    if func == name and filename.endswith(suffix):
                        cumulative[(suffix, name)] = cumulative.get((suffix, name), 0.0) + ct
    parts: dict[str, float] = {}
    for part, alternatives in _PROFILE_PARTS:
        parts[part] = 0.0
        for alternative in alternatives:
            if any(key in cumulative for key in alternative):
                parts[part] = sum(cumulative.get(key, 0.0) for key in alternative) / n_updates * 1e3
                break
    parts[REST] = total / n_updates * 1e3 - sum(parts.values())
    parts[PROFILE_TOTAL] = total / n_updates * 1e3
    return parts


# --- one process per arm ---------------------------------------------------------------------


def sbx_available() -> bool:
    return importlib.util.find_spec("sbx") is not None


def _build_model(algorithm: str) -> Any:
    if algorithm == "SBX":
        os.environ["XLA_FLAGS"] = SBX_XLA_FLAGS  # before JAX loads: it reads them once
        from sbx import SAC as SBXSAC  # optional (the bench extra), and it loads JAX

        return make_filled_model(SBXSAC)
    if algorithm == "FastSAC-compiled":
        return make_filled_model(FastSAC, update="compiled")
    if algorithm == "FastSAC-fused":
        return make_filled_model(FastSAC, update="fused")
    if algorithm == "matmuls":
        return UpdateMatmuls()
    return make_filled_model(FastSAC if algorithm == "FastSAC" else SAC)


def _worker(arm: str, connection: Any) -> None:
    """Builds the arm's model, then answers ("rate" | "profile", threads, n_updates) until None."""
    try:
        _role, algorithm, process_settings = _arm_spec(arm)[:3]
        if process_settings:
            configure_torch(1)
        model = _build_model(algorithm)
        warm_threads = None
        connection.send(("ready", None))
        while (message := connection.recv()) is not None:
            command, threads, n_updates = message
            th.set_num_threads(threads)
            if command == "profile":
                connection.send(("ok", profile_breakdown(model, n_updates)))
                continue
            if threads != warm_threads:  # first calls and a thread change: allocations, thread pool
                # (SBX jits its whole loop for each number of updates: warm it up on the block's)
                model.train(gradient_steps=n_updates if algorithm == "SBX" else WARMUP_UPDATES, batch_size=BATCH_SIZE)
                warm_threads = threads
            connection.send(("ok", update_rate(model, n_updates)))
    except Exception:  # noqa: BLE001 - the parent re-raises it with the arm's name
        connection.send(("error", traceback.format_exc()))


class _Arms:
    """The arms' worker processes (spawned: nothing inherited), asked one at a time."""

    def __init__(self, arms: list[str]):
        ctx = mp.get_context("spawn")
        self.workers = {}
        for arm in arms:
            parent, child = ctx.Pipe()
            process = ctx.Process(target=_worker, args=(arm, child), daemon=True, name=f"bench sac: {arm}")
            process.start()
            self.workers[arm] = (process, parent)
        for arm in arms:
            self._answer(arm)  # every model built before any timing starts

    def ask(self, arm: str, command: str, threads: int, n_updates: int) -> Any:
        self.workers[arm][1].send((command, threads, n_updates))
        return self._answer(arm)

    def _answer(self, arm: str) -> Any:
        try:
            status, value = self.workers[arm][1].recv()
        except EOFError:
            raise RuntimeError(f"bench sac: the worker of {arm!r} died "
                               f"(exit code {self.workers[arm][0].exitcode})") from None
        if status == "error":
            raise RuntimeError(f"bench sac: the worker of {arm!r} failed:\n{value}")
        return value

    def close(self) -> None:
        for process, connection in self.workers.values():
            try:
                connection.send(None)
            except OSError:
                pass
        for process, _connection in self.workers.values():
            process.join(timeout=30)
            if process.is_alive():
                process.terminate()
                process.join(timeout=5)

    def __enter__(self) -> _Arms:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _arm_spec(arm: str) -> tuple:
    return ARMS[arm] if arm in ARMS else EXTRA_ARMS[arm]


def arms_at(threads: int, arms: list[str]) -> list[str]:
    """The arms measured at a thread setting."""
    return [a for a in arms if a in ARMS or EXTRA_ARMS[a][3] is None or threads in EXTRA_ARMS[a][3]]


def interleaved_rates(arms: _Arms, threads: int, rounds: int, n_updates: int,
                      rng: np.random.Generator, progress: Any = None) -> dict[str, list[float]]:
    """Updates/s of each arm's blocks: one block per arm and round, the order shuffled per round."""
    names = arms_at(threads, list(arms.workers))
    rates: dict[str, list[float]] = {name: [] for name in names}
    for _ in range(rounds):
        for i in rng.permutation(len(names)):
            rates[names[i]].append(arms.ask(names[i], "rate", threads, n_updates))
            if progress is not None:
                progress.update(1)
    return rates


# --- the table -------------------------------------------------------------------------------


def ratio_name(threads: int) -> str:
    return f"updates/s {OURS} / {BASELINE}, {threads} thread{'s' if threads > 1 else ''}"


def build_table(block_rates: dict[int, dict[str, list[float]]], profile: dict[str, dict[str, float]],
                config: dict) -> BenchTable:
    """The table from the measured block rates (threads -> arm -> updates/s per block) and profile."""
    rows, ratios = [], {}
    for threads, rates in block_rates.items():
        median = {arm: statistics.median(r) for arm, r in rates.items()}
        for arm, r in rates.items():
            rows.append({"threads": threads, "config": arm, "role": _arm_spec(arm)[0], "updates/s": median[arm],
                         "min": min(r), "max": max(r), "ms/update": 1e3 / median[arm],
                         "/ SB3 SAC": median[arm] / median[BASELINE]})
        ratios[ratio_name(threads)] = median[OURS] / median[BASELINE]
    for threads, rates in block_rates.items():
        median = {arm: statistics.median(r) for arm, r in rates.items()}
        per = f"{threads} thread{'s' if threads > 1 else ''}"
        if COMPILED in median:
            ratios[f"updates/s {COMPILED} / {BASELINE}, {per}"] = median[COMPILED] / median[BASELINE]
            ratios[f"updates/s {COMPILED} / {OURS}, {per} (the compiled update alone)"] = (
                median[COMPILED] / median[OURS])
        if FUSED in median:
            ratios[f"updates/s {FUSED} / {BASELINE}, {per}"] = median[FUSED] / median[BASELINE]
            ratios[f"updates/s {FUSED} / {OURS}, {per} (the update by hand alone)"] = median[FUSED] / median[OURS]
            if COMPILED in median:
                ratios[f"updates/s {FUSED} / {COMPILED}, {per}"] = median[FUSED] / median[COMPILED]
        if SBX in median:
            if COMPILED in median:
                ratios[f"updates/s {COMPILED} / {SBX}, {per} (target: >= 1.0)"] = median[COMPILED] / median[SBX]
            if FUSED in median:
                ratios[f"updates/s {FUSED} / {SBX}, {per} (target: >= 1.0)"] = median[FUSED] / median[SBX]
            if MATMULS in median:
                ratios[f"{MATMULS} per s / {SBX} updates/s, {per} (the most any torch update can reach: "
                       "its matrix products alone)"] = median[MATMULS] / median[SBX]
            ratios[f"updates/s {OURS} / {SBX}, {per}"] = median[OURS] / median[SBX]
            ratios[f"updates/s {BASELINE} / {SBX}, {per}"] = median[BASELINE] / median[SBX]
    if 1 in block_rates and "SB3 SAC + configure_torch" in block_rates[1]:
        rates = block_rates[1]
        ratios["updates/s SB3 SAC + configure_torch / SB3 SAC, 1 thread (process settings alone)"] = (
            statistics.median(rates["SB3 SAC + configure_torch"]) / statistics.median(rates[BASELINE]))
    sbx = (f", sbx-rl {config['sbx']} on jax {config['jax']} ({SBX_XLA_FLAGS})" if config.get("sbx")
           else "")
    notes = [
        f"setup: stable-baselines3 {config['stable_baselines3']}, torch {config['torch']}{sbx}; MultiInputPolicy, Dict "
        "observations 26 + 2 + 2, action 9, actor and twin critics 2 x 256 ReLU, batch "
        f"{config['batch_size']}, ent_coef auto, a DictReplayBuffer of {config['buffer_size']:,} random "
        "transitions",
        f"method: {config['rounds']} rounds of one {config['updates_per_block']}-update block per arm (order "
        "shuffled per round, one process per arm, after an untimed warm-up); updates/s is the median block "
        "rate, min and max the slowest and fastest block; the block rates are in the .json (config)",
        "the ratio that counts is ours / baseline at 1 thread (what training uses); at 2 threads a second "
        "process on the other core makes OpenMP's threads wait on each other, so that figure holds for an idle "
        "machine only",
        f"{COMPILED}: FastSAC(update='compiled'), hingelab.learners.sac.compiled_update; torch.compile's "
        "compilation (tens of seconds) is in the untimed warm-up, as SBX's jit is",
        f"{FUSED}: FastSAC(update='fused'), hingelab.learners.sac.fused_update: no compilation",
        f"{MATMULS}: {UpdateMatmuls().flops / 1e6:.0f} MFLOP of matrix products per update (bench.sac.UpdateMatmuls), "
        "its rate a sequence's; MFLOP/s = that times its rate",
    ]
    if config.get("sbx"):
        notes.append(f"{SBX}: sbx.SAC with the same nets, batch and buffer, 1 thread only (XLA reads its thread "
                     "setting once); its train() samples all of a block's batches at once and runs the block as one "
                     "jitted loop")
    elif "sbx" in config:
        notes.append(f"{SBX}: not measured: sbx is not installed (pip install -e '.[bench]')")
    for threads, rates in block_rates.items():
        spread = {arm: max(r) / min(r) for arm, r in rates.items()}
        uneven = [f"{arm} {min(rates[arm]):.3g}-{max(rates[arm]):.3g}" for arm, x in spread.items()
                  if x > UNEVEN_BLOCKS]
        if uneven:
            notes.append(f"UNRELIABLE at {threads} thread{'s' if threads > 1 else ''}: block rates (updates/s) "
                         f"spread more than {UNEVEN_BLOCKS:g}x ({'; '.join(uneven)}): the machine was busy "
                         "during this run; do not read this thread setting's ratio")
    if profile:
        arms = list(profile)
        notes.append(f"cProfile, ms per update at 1 thread ({' / '.join(arms)}), {config['profile_updates']} "
                     "updates; cProfile inflates the Python-heavy parts (the compiled arms are not profiled: "
                     "cProfile does not see into a compiled graph):")
        for part in profile[arms[0]]:
            notes.append(f"  {part}: " + " / ".join(f"{profile[arm][part]:.2f}" for arm in arms))
    notes.append("why each change is faster, and an ablation: analysis/bench/history/sac_updates.md")
    title = ("SAC gradient updates per second: hingelab's FastSAC (eager, compiled and fused) vs bare "
             "stable-baselines3 SAC and SBX")
    return BenchTable(name="sac", title=title, columns=COLUMNS, rows=rows, ratios=ratios, notes=notes,
                      config={**config, "block_rates": {str(t): r for t, r in block_rates.items()},
                              "profile_ms_per_update": profile})


def run(quick: bool = False) -> BenchTable:
    threads_list = (1,) if quick else (1, 2)
    rounds = 3 if quick else 7
    n_updates = 20 if quick else 200
    profile_updates = 20 if quick else 200
    arms_run = [*ARMS, COMPILED, FUSED, MATMULS]
    sbx_version = jax_version = None
    if sbx_available():
        from importlib.metadata import version

        arms_run.append(SBX)
        sbx_version, jax_version = version("sbx-rl"), version("jax")
    else:
        print(f"bench sac: sbx is not installed: the {SBX} arm is skipped (pip install -e '.[bench]')")
    config = {"quick": quick, "threads": list(threads_list), "rounds": rounds, "updates_per_block": n_updates,
              "profile_updates": profile_updates, "batch_size": BATCH_SIZE, "buffer_size": BUFFER_SIZE,
              "seed": SEED, "torch": torch.__version__, "stable_baselines3": stable_baselines3.__version__,
              "sbx": sbx_version, "jax": jax_version, "arms": arms_run}
    rng = np.random.default_rng(SEED)
    block_rates: dict[int, dict[str, list[float]]] = {}
    blocks = sum(rounds * len(arms_at(threads, arms_run)) for threads in threads_list)
    with tqdm(total=blocks + len(ARMS), desc="bench sac: starting the workers (and compiling)",
              unit="block") as progress, _Arms(arms_run) as arms:
        progress.set_description("bench sac")
        for threads in threads_list:
            block_rates[threads] = interleaved_rates(arms, threads, rounds, n_updates, rng, progress)
        profile = {}
        for arm in ARMS:
            profile[arm] = arms.ask(arm, "profile", 1, profile_updates)
            progress.update(1)
    return build_table(block_rates, profile, config)

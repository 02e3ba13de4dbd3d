"""``hingelab bench train``: SAC update rate, env steps/s while training, replay pre-fill rate.

Measurements, each ours against a bare stable-baselines3 baseline in the same run:

1. Updates per second: ``SAC.train`` on the low-level task's spaces (Dict observations,
   2 x 256 ReLU, batch 256, buffers holding the same transitions): bare SB3 ``SAC`` at
   torch's default threads vs the trainer's algorithm and thread setting, in alternating
   blocks (the median block rate each).
2. Environment steps per second of a whole training loop on ToolShape-v0 after the random
   warm-up, at equal work: one env and the same updates per env step (UTD 1 and UTD 2), the same
   twin critics. Bare ``SAC.learn`` against ``train_low --envs 1`` (recording every rollout) in
   its serial loop and with ``--overlap`` (the updates run while an env process computes the
   step: ``hingelab.learners.sac.overlap``); the overlapped loop is also compared with the serial.
3. Replay pre-fill from MCAP: transitions per second from a dataset on disk into an SB3
   buffer: per-transition ``buffer.add`` (SB3's way) vs ``prefill_replay_buffer``.
4. The same as 2 on ToolPick-v0 (the shipped low-level policy inside, perception on):
   bare ``SAC.learn`` against ``train_high --envs 1 --no-prior``, serial and overlapped.
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import DictReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import configure

from hingelab.bench.table import BenchTable
from hingelab.episodes.dataset import Dataset
from hingelab.episodes.transitions import dataset_transitions, fill_replay_buffer
from hingelab.learners.sac.high_level import train_high
from hingelab.learners.sac.high_level_config import HighLevelTrainConfig
from hingelab.learners.sac.low_level import build_model, train_low
from hingelab.learners.sac.low_level_config import LowLevelTrainConfig
from hingelab.learners.sac.run import algorithm_class
from hingelab.rollouts.low_level import make_eval_env
from hingelab.training.buffer_fill import prefill_replay_buffer

# the code and models this benchmark measures (the bench module itself: hingelab.bench.measured_paths):
# `hingelab train low` whole (its envs, recording, replay pre-fill, reports) and its algorithm
MEASURES = ("platform/hingelab/learners", "platform/hingelab/training", "platform/hingelab/rollouts",
            "platform/hingelab/policies", "platform/hingelab/envs", "platform/hingelab/sim",
            "platform/hingelab/perception", "platform/hingelab/episodes", "platform/hingelab/analysis", "assets")

SEED = 0


def _random_fill(buffer, n: int, rng: np.random.Generator) -> None:
    spaces = buffer.observation_space.spaces
    obs = {k: rng.normal(size=(n, 1) + s.shape) for k, s in spaces.items()}
    nxt = {k: rng.normal(size=(n, 1) + s.shape) for k, s in spaces.items()}
    for k in spaces:
        buffer.observations[k][:n] = obs[k]
        buffer.next_observations[k][:n] = nxt[k]
    buffer.actions[:n] = rng.uniform(-1, 1, size=(n, 1) + buffer.action_space.shape)
    buffer.rewards[:n] = rng.uniform(0, 1, size=(n, 1))
    buffer.pos = n


def _updates_per_s(model, n: int, batch: int, threads: int) -> float:
    torch.set_num_threads(threads)
    start = time.perf_counter()
    model.train(gradient_steps=n, batch_size=batch)
    return n / (time.perf_counter() - start)


def bench_updates(blocks: int, per_block: int, rows: list, ratios: dict, notes: list) -> None:
    default_threads = torch.get_num_threads()
    config = LowLevelTrainConfig(buffer_size=20_000)
    env = make_eval_env({})
    bare = SAC("MultiInputPolicy", env, buffer_size=config.buffer_size, batch_size=config.batch_size, seed=SEED,
               policy_kwargs={"net_arch": [256, 256], "activation_fn": torch.nn.ReLU}, device="cpu")
    ours = build_model(config, env)
    rng = np.random.default_rng(SEED)
    for model in (bare, ours):
        model.set_logger(configure(folder=None, format_strings=[]))
        _random_fill(model.replay_buffer, 10_000, np.random.default_rng(SEED))
        model.train(gradient_steps=20, batch_size=config.batch_size)  # warm-up (allocations, first calls)
    # bare SB3 at torch's default threads (what a user gets) and at one thread (the same core
    # budget as ours), so the table separates the thread setting from FastSAC's changes
    arms = [("bare", bare, default_threads), ("bare_1", bare, 1), ("ours", ours, config.torch_threads)]
    rates = {name: [] for name, _, _ in arms}
    for _ in range(blocks):
        order = list(arms)
        rng.shuffle(order)
        for name, model, threads in order:
            rates[name].append(_updates_per_s(model, per_block, config.batch_size, threads))
    torch.set_num_threads(default_threads)
    env.close()
    median = {name: statistics.median(r) for name, r in rates.items()}
    ours_label = f"{algorithm_class(config).__name__}, {config.torch_threads} thread(s)"
    for name, label in (("bare", f"bare SB3 SAC, torch default threads ({default_threads})"),
                        ("bare_1", "bare SB3 SAC, 1 thread")):
        rows.append({"what": "SAC updates/s (batch 256, 2x256)", "baseline": label, "baseline rate": median[name],
                     "ours": ours_label, "our rate": median["ours"], "ours / baseline": median["ours"] / median[name]})
    ratios["updates/s ours / bare SB3"] = median["ours"] / median["bare"]
    ratios["updates/s ours / bare SB3 on 1 thread"] = median["ours"] / median["bare_1"]
    notes.append(f"updates: {blocks} alternating blocks of {per_block} updates per arm (order shuffled per block), "
                 "median block rate; block rates " +
                 "; ".join(f"{name} {', '.join(f'{r:.0f}' for r in rates[name])}" for name, _, _ in arms))


def _bare_learn_rate(warmup: int, steps: int, gradient_steps: int = 1, env=None) -> float:
    class Clock(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps == warmup:
                self.start = time.perf_counter()
            return True

    env = env if env is not None else make_eval_env({})
    policy = "MultiInputPolicy" if hasattr(env.observation_space, "spaces") else "MlpPolicy"
    model = SAC(policy, env, learning_starts=warmup, batch_size=256, gradient_steps=gradient_steps, seed=SEED,
                device="cpu", policy_kwargs={"net_arch": [256, 256], "activation_fn": torch.nn.ReLU})
    clock = Clock()
    model.learn(warmup + steps, callback=clock)
    rate = steps / (time.perf_counter() - clock.start)
    env.close()
    return rate


def _our_learn_rate(train, config, warmup: int, steps: int, run_dir: Path, **quiet) -> float:
    """Env steps/s of ``train(config, run_dir)`` (train_low or train_high) from its first update on;
    ``quiet``: the config's smallest evaluation (its evaluations run outside the timed steps)."""
    config = replace(config, steps=warmup + steps, learning_starts=warmup, eval_every=10**9,
                     checkpoint_every=10**9, **quiet)
    train(config, run_dir, progress=False)
    rows = pd.read_csv(run_dir / "metrics.csv")
    return float(rows["env_steps_per_s_learning"].iloc[-1])  # timed from the first update on


UTDS = (1, 2)  # updates per env step of every loop compared (1 env: gradient_steps = UTD)
ARMS = ("bare", "serial", "overlap", "overlap_fused")  # ours: the serial loop, overlapped, overlapped + fused update


def _arm_config(base, arm: str, utd: int):
    return replace(base, gradient_steps=utd, overlap=arm != "serial", update="fused" if arm == "overlap_fused" else
                   base.update)


def _equal_work_rows(level: str, command: str, bare_env, rates: dict, rows: list, ratios: dict) -> None:
    """The rows and ratios of one level's loops: ``rates[(arm, utd)]`` for arms bare, serial, overlap and
    overlap_fused (the overlapped loop with ``--update fused``)."""
    for utd in UTDS:
        what = f"{level} env steps/s while training, 1 env, {utd} update{'s' if utd > 1 else ''}/step"
        bare, serial, overlap, fused = (rates[(arm, utd)] for arm in ARMS)
        flags = f"--envs 1{' --gradient-steps 2' if utd == 2 else ''}"
        ours_serial, ours_overlap = f"{command} {flags} (recording)", f"{command} {flags} --overlap (recording)"
        ours_fused = f"{command} {flags} --overlap --update fused (recording)"
        bare_name = f"bare SB3 SAC.learn{bare_env}"
        for baseline, baseline_rate, ours, rate in ((bare_name, bare, ours_serial, serial),
                                                    (bare_name, bare, ours_overlap, overlap),
                                                    (ours_serial, serial, ours_overlap, overlap),
                                                    (bare_name, bare, ours_fused, fused)):
            rows.append({"what": what, "baseline": baseline, "baseline rate": baseline_rate, "ours": ours,
                         "our rate": rate, "ours / baseline": rate / baseline_rate})
        ratios[f"{level} UTD {utd}: serial / bare"] = serial / bare
        ratios[f"{level} UTD {utd}: overlapped / bare"] = overlap / bare
        ratios[f"{level} UTD {utd}: overlapped / serial"] = overlap / serial
        ratios[f"{level} UTD {utd}: overlapped, fused update / bare (target: >= 1.8)"] = fused / bare


def bench_learn(warmup: int, steps: int, rows: list, ratios: dict, notes: list, tmp: Path) -> Path:
    base = LowLevelTrainConfig(seed=SEED, n_envs=1)
    rates = {}
    for utd in UTDS:
        rates[("bare", utd)] = _bare_learn_rate(warmup, steps, gradient_steps=utd)
        for arm in ARMS[1:]:
            rates[(arm, utd)] = _our_learn_rate(train_low, _arm_config(base, arm, utd), warmup, steps,
                                                tmp / f"low_{arm}_{utd}", eval_goals_per_region=1)
    _equal_work_rows("low-level", "hingelab train low", "", rates, rows, ratios)
    notes.append(f"low-level training loops: {warmup} random warm-up steps, then {steps} steps with updates; the "
                 "bare loop and ours are both timed from the end of the warm-up; arms in the order bare, serial, "
                 "overlapped, overlapped with the fused update (hingelab.learners.sac.fused_update), UTD 1 then UTD 2")
    return tmp / "low_serial_1" / "dataset"


def bench_learn_high(warmup: int, steps: int, rows: list, ratios: dict, notes: list, tmp: Path) -> None:
    base = HighLevelTrainConfig(seed=SEED, prior=False, n_envs=1)
    rates = {}
    for utd in UTDS:
        env = gym.make(base.env_id, **base.env_arguments())
        rates[("bare", utd)] = _bare_learn_rate(warmup, steps, gradient_steps=utd, env=env)
        for arm in ARMS[1:]:
            rates[(arm, utd)] = _our_learn_rate(train_high, _arm_config(base, arm, utd), warmup, steps,
                                                tmp / f"high_{arm}_{utd}", eval_episodes=1)
    _equal_work_rows("high-level", "hingelab train high --no-prior", " on ToolPick-v0", rates, rows, ratios)
    notes.append(f"high-level training loops: ToolPick-v0 over the shipped low-level policy, {warmup} random warm-up "
                 f"steps, then {steps} steps with updates, timed from the end of the warm-up")


def bench_prefill(dataset: Path, repeats: int, rows: list, ratios: dict, notes: list) -> None:
    env = make_eval_env({})
    spaces = env.observation_space, env.action_space
    env.close()
    slow_rates, fast_rates = [], []
    n = 0
    for _ in range(repeats):
        buffer = DictReplayBuffer(100_000, *spaces, n_envs=1)
        start = time.perf_counter()
        n = fill_replay_buffer(buffer, dataset_transitions(Dataset(dataset)))
        slow_rates.append(n / (time.perf_counter() - start))
        buffer = DictReplayBuffer(100_000, *spaces, n_envs=2)
        stats = prefill_replay_buffer(buffer, [dataset])
        fast_rates.append(stats.transitions_per_s)
    slow, fast = statistics.median(slow_rates), statistics.median(fast_rates)
    rows.append({"what": "replay pre-fill from MCAP (transitions/s)", "baseline": "read + SB3 buffer.add per "
                 "transition", "baseline rate": slow, "ours": "prefill_replay_buffer (bulk)", "our rate": fast,
                 "ours / baseline": fast / slow})
    ratios["replay pre-fill ours / per-transition add"] = fast / slow
    notes.append(f"pre-fill: {n} transitions of {len(Dataset(dataset))} episodes (the rollouts of the serial UTD 1 "
                 f"low-level run), read from disk each time, median of {repeats}")


def run(quick: bool = False) -> BenchTable:
    rows, ratios, notes = [], {}, []
    notes.append("load average (1, 5, 15 min) at the start: " + ", ".join(f"{v:.2f}" for v in os.getloadavg()))
    bench_updates(3 if quick else 7, 20 if quick else 200, rows, ratios, notes)
    with tempfile.TemporaryDirectory() as tmp:
        dataset = bench_learn(100 if quick else 1000, 60 if quick else 1000, rows, ratios, notes, Path(tmp))
        bench_prefill(dataset, 2 if quick else 5, rows, ratios, notes)
        bench_learn_high(100 if quick else 500, 60 if quick else 1000, rows, ratios, notes, Path(tmp))
    return BenchTable(name="train", title="SAC training: update rate, env steps/s at equal work (low and high level, "
                                          "serial and overlapped), replay pre-fill",
                      columns=["what", "baseline", "baseline rate", "ours", "our rate", "ours / baseline"],
                      rows=rows, ratios=ratios, notes=notes, config={"quick": quick})

"""``hingelab bench train``: SAC update rate, env steps/s while training, replay pre-fill rate.

Three measurements, each ours against a bare stable-baselines3 baseline in the same run:

1. Updates per second: ``SAC.train`` on the low-level task's spaces (Dict observations,
   2 x 256 ReLU, batch 256, buffers holding the same transitions): bare SB3 ``SAC`` at
   torch's default threads vs the trainer's algorithm and thread setting, in alternating
   blocks (the median block rate each).
2. Environment steps per second of a whole training loop on ToolShape-v0 after the
   random warm-up: bare ``SAC.learn`` on one env with 1 update per step vs ``train_low``
   (recording every rollout) with the same 1 env / 1 update per step, and with its
   defaults (2 env processes, 1 update per 2 steps).
3. Replay pre-fill from MCAP: transitions per second from a dataset on disk into an SB3
   buffer: per-transition ``buffer.add`` (SB3's way) vs ``prefill_replay_buffer``.
4. High-level env steps per second while training on ToolPick-v0 (the shipped low-level policy
   inside, perception on): bare ``SAC.learn`` on one env with 1 update per step vs ``train_high``
   (recording every rollout, no prior) with 1 env / 1 update per step and with its defaults
   (2 env processes, 1 update per 2 steps).
"""

from __future__ import annotations

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


def _bare_learn_rate(warmup: int, steps: int, env=None) -> float:
    class Clock(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps == warmup:
                self.start = time.perf_counter()
            return True

    env = env if env is not None else make_eval_env({})
    policy = "MultiInputPolicy" if hasattr(env.observation_space, "spaces") else "MlpPolicy"
    model = SAC(policy, env, learning_starts=warmup, batch_size=256, seed=SEED, device="cpu",
                policy_kwargs={"net_arch": [256, 256], "activation_fn": torch.nn.ReLU})
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


def bench_learn(warmup: int, steps: int, rows: list, ratios: dict, notes: list, tmp: Path) -> Path:
    base = LowLevelTrainConfig(seed=SEED)
    bare = _bare_learn_rate(warmup, steps)
    same = _our_learn_rate(train_low, replace(base, n_envs=1), warmup, steps, tmp / "one_env", eval_goals_per_region=1)
    default = _our_learn_rate(train_low, base, warmup, steps, tmp / "defaults", eval_goals_per_region=1)
    rows.append({"what": "env steps/s while training, 1 env, 1 update/step", "baseline": "bare SB3 SAC.learn",
                 "baseline rate": bare, "ours": "hingelab train low --envs 1 (recording)", "our rate": same,
                 "ours / baseline": same / bare})
    rows.append({"what": "env steps/s while training, defaults", "baseline": "bare SB3 SAC.learn",
                 "baseline rate": bare, "ours": f"hingelab train low (--envs {base.n_envs}, 1 update per "
                 f"{base.n_envs} steps)", "our rate": default, "ours / baseline": default / bare})
    ratios["training env steps/s, same updates per step, ours / bare"] = same / bare
    ratios["training env steps/s, defaults, ours / bare"] = default / bare
    notes.append(f"training loops: {warmup} random warm-up steps, then {steps} steps with updates; the bare "
                 "loop and ours are both timed from the end of the warm-up")
    return tmp / "defaults" / "dataset"


def bench_learn_high(warmup: int, steps: int, rows: list, ratios: dict, notes: list, tmp: Path) -> None:
    base = HighLevelTrainConfig(seed=SEED, prior=False)
    bare = _bare_learn_rate(warmup, steps, env=gym.make(base.env_id, **base.env_arguments()))
    same = _our_learn_rate(train_high, replace(base, n_envs=1), warmup, steps, tmp / "high_one_env", eval_episodes=1)
    default = _our_learn_rate(train_high, base, warmup, steps, tmp / "high_defaults", eval_episodes=1)
    rows.append({"what": "high-level env steps/s while training, 1 env, 1 update/step",
                 "baseline": "bare SB3 SAC.learn on ToolPick-v0", "baseline rate": bare,
                 "ours": "hingelab train high --envs 1 --no-prior (recording)", "our rate": same,
                 "ours / baseline": same / bare})
    rows.append({"what": "high-level env steps/s while training, defaults", "baseline": "bare SB3 SAC.learn on "
                 "ToolPick-v0", "baseline rate": bare, "ours": f"hingelab train high --no-prior (--envs "
                 f"{base.n_envs}, 1 update per {base.n_envs} steps)", "our rate": default,
                 "ours / baseline": default / bare})
    ratios["high-level training env steps/s, same updates per step, ours / bare"] = same / bare
    ratios["high-level training env steps/s, defaults, ours / bare"] = default / bare
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
    notes.append(f"pre-fill: {n} transitions of {len(Dataset(dataset))} episodes (the defaults run's rollouts), "
                 f"read from disk each time, median of {repeats}")


def run(quick: bool = False) -> BenchTable:
    rows, ratios, notes = [], {}, []
    bench_updates(3 if quick else 7, 20 if quick else 200, rows, ratios, notes)
    with tempfile.TemporaryDirectory() as tmp:
        dataset = bench_learn(100 if quick else 1000, 60 if quick else 1000, rows, ratios, notes, Path(tmp))
        bench_prefill(dataset, 2 if quick else 5, rows, ratios, notes)
        bench_learn_high(100 if quick else 500, 60 if quick else 1000, rows, ratios, notes, Path(tmp))
    return BenchTable(name="train", title="SAC training: update rate, env steps/s (low and high level), replay "
                                          "pre-fill",
                      columns=["what", "baseline", "baseline rate", "ours", "our rate", "ours / baseline"],
                      rows=rows, ratios=ratios, notes=notes, config={"quick": quick})

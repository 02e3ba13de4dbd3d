"""Heuristic demos: run the privileged heuristic on ToolPick-v0 and record every episode.

``generate_heuristic_dataset`` is what ``hingelab generate heuristic`` runs. Episode k of a
dataset made with seed S is reset with seed ``hingelab.seeds.demo_seed(S, k)``, so the same seed gives the
same episodes whatever the number of worker processes (each worker writes its episodes
into the one dataset folder; the writer's unique names and atomic renames make that safe), and
whether they run in local worker processes or as Ray tasks (``ray_address``: one task per episode,
``hingelab.workers.ray_fan_out``).
"""

from __future__ import annotations

import functools
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from tqdm import tqdm

from hingelab.disk_full import disk_full_error, is_disk_full
from hingelab.envs import TOOL_PICK_ID
from hingelab.envs.recording import RecordingWrapper
from hingelab.episodes import create_dataset
from hingelab.episodes.card import load_card
from hingelab.episodes.dataset import Dataset
from hingelab.errors import ConfigError
from hingelab.heuristic.controller import PrivilegedHeuristic
from hingelab.provenance import differing_settings
from hingelab.rollouts.heuristic_config import HeuristicRunConfig
from hingelab.seeds import demo_seed
from hingelab.sim.finger_synergy import FingerSynergy
from hingelab.sim.mesh_objects import is_mesh, mesh_sha256, object_label
from hingelab.workers.local_pool import map_unordered
from hingelab.workers.ray_fan_out import fan_out


@dataclass
class EpisodeSummary:
    seed: int
    success: bool
    first_attempt_success: bool
    attempts: int
    length: int
    episode_return: float
    failure_reason: str | None




def make_env(config: HeuristicRunConfig, dataset_dir: Path | None = None):
    """ToolPick-v0 for ``config`` (privileged low level), recorded into ``dataset_dir`` if given."""

    env = gym.make(TOOL_PICK_ID, object=config.object, size=config.size, mass=config.mass,
                   randomize=config.randomize, max_episode_steps=config.max_episode_steps,
                   object_noise=config.object_noise, object_noise_model=config.object_noise_model)
    if dataset_dir is not None:
        extra = {"object_size": config.size}
        if is_mesh(config.object):  # object "mesh:<file name>"; the file's content named by its hash
            extra["object_mesh_sha256"] = mesh_sha256(config.object)
        env = RecordingWrapper(env, dataset_dir, source="heuristic", object_name=object_label(config.object),
                               action_level="high", extra_metadata=extra)
    return env


def run_episode(env, seed: int) -> EpisodeSummary:
    """One heuristic episode on a (recorded) ToolPick-v0 env."""

    env.reset(seed=seed)
    pick = env.unwrapped
    heuristic = PrivilegedHeuristic(pick.sim, FingerSynergy.load(), pick.object)
    heuristic.reset(pick.state, pick.target)
    total, length, info = 0.0, 0, {}
    while True:
        command = heuristic.act(pick.state)
        pick.command_privileged(command.arm_velocity, command.hinge_target, command.hand_targets)
        _, reward, terminated, truncated, info = env.step(np.zeros(5))
        total += reward
        length += 1
        if terminated or truncated:
            break
    success = bool(info.get("is_success", 0.0))
    return EpisodeSummary(seed, success, bool(info.get("first_attempt_success", 0.0)), int(info.get("attempt", 1)),
                          length, total, None if success else info.get("failure_reason", "timeout"))


# --- worker processes ----------------------------------------------------------------------
_WORKER: dict = {}


def _init_worker(config: HeuristicRunConfig, dataset_dir: str) -> None:

    torch.set_num_threads(1)  # one core per worker process
    _WORKER["env"] = make_env(config, Path(dataset_dir))


def _run_in_worker(seed: int) -> EpisodeSummary:
    return run_episode(_WORKER["env"], seed)


class HeuristicEpisodes:
    """The episode runner of a Ray task (``hingelab.workers.ray_fan_out``): its env is built on the first
    episode, in the worker process, and kept for the next ones."""

    def __init__(self, config: HeuristicRunConfig, dataset_dir: str):
        self.config, self.dataset_dir, self.env = config, dataset_dir, None

    def __call__(self, seed: int) -> EpisodeSummary:
        if self.env is None:

            torch.set_num_threads(1)  # one core per task
            self.env = make_env(self.config, Path(self.dataset_dir))
        return run_episode(self.env, seed)

    def close(self) -> None:
        if self.env is not None:
            self.env.close()
            self.env = None


RESUMABLE = ("episodes", "workers")  # what --resume may change; any other setting must match the card's


def _seeds_to_run(out: Path, config: HeuristicRunConfig, resume: bool) -> list[int]:
    """The episode seeds this run writes: all of them, or (``resume``) those the folder lacks."""

    seeds = [demo_seed(config.seed, k) for k in range(config.episodes)]
    existing = list((out / "episodes").glob("*.mcap")) if (out / "episodes").is_dir() else []
    if not resume:
        if existing:
            raise ConfigError(f"{out} already holds {len(existing)} episodes; write into a new --out folder "
                              "(a dataset is the output of one run), delete it, or continue a stopped run "
                              "with --resume")
        return seeds
    if not (out / "dataset.json").exists():
        raise ConfigError(f"--resume: {out} holds no dataset to continue; leave --resume out to start one")
    # a card from before the object noise: made with the default
    recorded = {"object_noise": "gaussian", "object_noise_model": None, **(load_card(out).config or {})}
    differ = differing_settings(recorded, asdict(config), ignore=RESUMABLE)
    if differ:
        raise ConfigError(f"--resume: {out} was made with other settings ("
                          + ", ".join(f"{k} {old!r}, now {new!r}" for k, (old, new) in differ.items())
                          + "); give the same ones, or a new --out")
    for partial in (out / "episodes").glob("*.partial"):  # unfinished writes of the stopped run: redone
        partial.unlink()
    done = set(Dataset(out).index["seed"].dropna().astype(int))
    return [s for s in seeds if s not in done]


def generate_heuristic_dataset(out: Path, config: HeuristicRunConfig, progress: bool = True,
                               name: str | None = None, resume: bool = False,
                               ray_address: str | None = None) -> list[EpisodeSummary]:
    """Write ``config.episodes`` heuristic episodes into a new dataset at ``out``; ``resume``: only the
    episodes (seeds) a stopped run into ``out`` did not finish, so the folder ends as one
    uninterrupted run's would. A full disk stops with ``DiskFullError`` (the finished episodes kept).
    ``ray_address``: episodes as Ray tasks on that cluster (``"local"``: a local Ray of
    ``config.workers`` CPUs, or of every core when ``config.workers`` is 1)."""

    if config.episodes < 1:
        raise ConfigError(f"--episodes must be at least 1, not {config.episodes}")
    if config.workers < 1:
        raise ConfigError(f"--workers must be at least 1, not {config.workers}")
    make_env(config).close()  # bad object, size or mass: a clear error before any file is made
    out = Path(out)
    seeds = _seeds_to_run(out, config, resume)
    if not resume:
        create_dataset(out, name=name or out.name, source="heuristic", config=asdict(config), seed=config.seed,
                       description=f"privileged heuristic demos on ToolPick-v0, {object_label(config.object)} "
                                   f"{config.size * 100:g} cm")
    try:
        if ray_address is not None:
            return _generate_on_ray(out, config, seeds, progress, ray_address)
        return _generate(out, config, seeds, progress)
    except OSError as exc:
        if not is_disk_full(exc):
            raise
        kept = len(list((out / "episodes").glob("*.mcap")))
        command = (f"hingelab generate heuristic --out {out} --episodes {config.episodes} --object {config.object} "
                   f"--size {config.size:g} --mass {config.mass:g} --seed {config.seed}"
                   + ("" if config.randomize else " --no-randomize")
                   + ("" if config.object_noise == "gaussian" else f" --object-noise {config.object_noise}")
                   + (f" --object-noise-model {config.object_noise_model}" if config.object_noise_model else ""))
        raise disk_full_error(out, kept, config.episodes, command) from exc


def _generate(out: Path, config: HeuristicRunConfig, seeds: list[int], progress: bool) -> list[EpisodeSummary]:

    bar = tqdm(total=len(seeds), desc=f"heuristic {object_label(config.object)}", unit="episode",
               disable=not progress)
    summaries: list[EpisodeSummary] = []
    if config.workers == 1:
        _init_worker(config, str(out))
        try:
            for seed in seeds:
                summaries.append(_run_in_worker(seed))
                bar.update()
                bar.set_postfix(success=f"{np.mean([s.success for s in summaries]):.0%}")
        finally:
            _WORKER.pop("env").close()
    else:
        for summary in map_unordered(_run_in_worker, seeds, config.workers, _init_worker, (config, str(out))):
            summaries.append(summary)
            bar.update()
            bar.set_postfix(success=f"{np.mean([s.success for s in summaries]):.0%}")
    bar.close()
    return sorted(summaries, key=lambda s: s.seed)


def _generate_on_ray(out: Path, config: HeuristicRunConfig, seeds: list[int], progress: bool,
                     address: str) -> list[EpisodeSummary]:

    summaries = fan_out(functools.partial(HeuristicEpisodes, config, str(out)), seeds, address=address,
                        num_cpus=config.workers if config.workers > 1 else None, progress=progress,
                        desc=f"heuristic {object_label(config.object)}")
    return sorted(summaries, key=lambda s: s.seed)


def summarize(summaries: list[EpisodeSummary], seconds: float) -> str:
    n = len(summaries)
    success = np.mean([s.success for s in summaries])
    first = np.mean([s.first_attempt_success for s in summaries])
    length = np.mean([s.length for s in summaries])
    reasons = {}
    for s in summaries:
        if s.failure_reason:
            reasons[s.failure_reason] = reasons.get(s.failure_reason, 0) + 1
    failures = ", ".join(f"{k} {v}" for k, v in sorted(reasons.items())) or "none"
    return (f"{n} episodes in {seconds:.0f} s: success {success:.1%} ({first:.1%} at the first attempt), "
            f"mean length {length:.1f} steps; failures: {failures}.")


def timed(fn, *args, **kwargs):
    start = time.perf_counter()
    result = fn(*args, **kwargs)
    return result, time.perf_counter() - start

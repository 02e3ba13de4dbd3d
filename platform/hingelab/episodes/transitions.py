"""Episodes -> transitions for replay buffers (incl. stable-baselines3) and a flat pandas frame.

A transition t is (obs_t, action_t, reward_t, next_obs_t, terminated_t, truncated_t,
info_t) from the ``/step`` record; next_obs_t is obs_{t+1}, and for the last step
the episode's final observation (``EpisodeWriter.write_final_observation``). An
episode without one (a recovered file) loses its last transition, which has no
next observation.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from hingelab.episodes import schemas as S
from hingelab.episodes.reader import Episode

OBS_KEYS = ("observation", "achieved_goal", "desired_goal")


@dataclass
class Transitions:
    """Stacked transitions. observations / next_observations: (N, D) arrays, or a dict of them
    (goal envs: observation, achieved_goal, desired_goal); actions (N, A); rewards, terminated,
    truncated (N,); infos: {name: (N,)}; episode_index (N,) int: which episode each came from."""

    observations: np.ndarray | dict
    next_observations: np.ndarray | dict
    actions: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    infos: dict
    episode_index: np.ndarray

    def __len__(self) -> int:
        return len(self.rewards)

    @property
    def is_dict(self) -> bool:
        return isinstance(self.observations, dict)


def episode_transitions(episode: Episode, episode_index: int = 0) -> Transitions:
    step = episode.topics[S.TOPIC_STEP]
    keys = [k for k in OBS_KEYS if k in step]
    n = len(step["reward"])
    has_final = all(k in episode.final for k in keys)
    m = n if has_final else n - 1  # without a final observation the last step has no next_obs
    obs = {k: step[k][:m] for k in keys}
    next_obs = {k: (np.concatenate([step[k][1:], episode.final[k][None]]) if has_final else step[k][1:n])
                for k in keys}
    flat = keys == ["observation"]
    return Transitions(
        observations=obs["observation"] if flat else obs,
        next_observations=next_obs["observation"] if flat else next_obs,
        actions=step["action"][:m], rewards=step["reward"][:m],
        terminated=step["terminated"][:m], truncated=step["truncated"][:m],
        infos={k[len("info."):]: v[:m] for k, v in step.items() if k.startswith("info.")},
        episode_index=np.full(m, episode_index, dtype=np.int64),
    )


def concat_transitions(parts: Iterable[Transitions]) -> Transitions:
    parts = list(parts)
    if not parts:
        raise ValueError("no episodes to take transitions from")

    def cat(values):
        if isinstance(values[0], dict):
            return {k: np.concatenate([v[k] for v in values]) for k in values[0]}
        return np.concatenate(values)

    return Transitions(
        observations=cat([p.observations for p in parts]), next_observations=cat([p.next_observations for p in parts]),
        actions=cat([p.actions for p in parts]), rewards=cat([p.rewards for p in parts]),
        terminated=cat([p.terminated for p in parts]), truncated=cat([p.truncated for p in parts]),
        infos={k: np.concatenate([p.infos[k] for p in parts]) for k in parts[0].infos},
        episode_index=np.concatenate([p.episode_index for p in parts]),
    )


def dataset_transitions(dataset) -> Transitions:
    """All transitions of a ``Dataset`` (reads only ``/step``: no clouds are read)."""
    return concat_transitions(episode_transitions(ep, i)
                              for i, ep in enumerate(dataset.iter_episodes(topics=[S.TOPIC_STEP])))


def fill_replay_buffer(buffer, transitions: Transitions) -> int:
    """Add transitions to a stable-baselines3 ``ReplayBuffer`` / ``DictReplayBuffer`` (n_envs=1).

    ``done`` is terminated or truncated; a truncation that is not a termination is passed as
    ``TimeLimit.truncated`` so SB3 bootstraps through it. Returns the number added.
    """
    for i in range(len(transitions)):
        if transitions.is_dict:
            obs = {k: v[i][None] for k, v in transitions.observations.items()}
            next_obs = {k: v[i][None] for k, v in transitions.next_observations.items()}
        else:
            obs, next_obs = transitions.observations[i][None], transitions.next_observations[i][None]
        terminated, truncated = bool(transitions.terminated[i]), bool(transitions.truncated[i])
        info = {k: float(v[i]) for k, v in transitions.infos.items()}
        info["TimeLimit.truncated"] = truncated and not terminated
        buffer.add(obs, next_obs, transitions.actions[i][None], np.array([transitions.rewards[i]]),
                   np.array([terminated or truncated]), [info])
    return len(transitions)


def _expand(prefix: str, array: np.ndarray) -> dict:
    if array.ndim == 1:
        return {prefix: array}
    flat = array.reshape(len(array), -1)
    return {f"{prefix}_{j}": flat[:, j] for j in range(flat.shape[1])}


def episode_frame(episode: Episode, topics: Iterable[str] | None = None) -> pd.DataFrame:
    """One row per step: episode facts, time, every ``/step`` field (vectors as ``name_i``
    columns) and the fields of other per-step topics as ``<topic>:<field>[_i]``. Clouds are left out."""
    step = episode.topics[S.TOPIC_STEP]
    n = len(step["log_time_ns"])
    columns = {"episode_id": [episode.metadata.get(S.KEY_EPISODE_ID, episode.path.stem)] * n,
               "step": np.arange(n), "time_s": step["log_time_ns"] / 1e9}
    for key in (S.KEY_SOURCE, S.KEY_OBJECT, S.KEY_SEED, S.KEY_SUCCESS):
        columns[key] = [episode.metadata.get(key)] * n
    for name, array in step.items():
        if name != "log_time_ns":
            columns.update(_expand(name, array))
    for topic in topics if topics is not None else episode.topics:
        if topic in (S.TOPIC_STEP, S.TOPIC_POINTS) or topic not in episode.topics:
            continue
        fields = episode.topics[topic]
        if len(fields["log_time_ns"]) != n:
            continue  # not logged once per step: not a column of a per-step frame
        for name, array in fields.items():
            if name != "log_time_ns":
                columns.update(_expand(f"{topic}:{name}", array))
    return pd.DataFrame(columns)


def dataset_frame(dataset, topics: Iterable[str] | None = None) -> pd.DataFrame:
    """All episodes of a ``Dataset`` as one flat frame (see ``episode_frame``)."""
    frames = [episode_frame(ep, topics) for ep in dataset.iter_episodes(
        topics=None if topics is None else [S.TOPIC_STEP, *topics])]
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


__all__ = ["Transitions", "episode_transitions", "concat_transitions", "dataset_transitions",
           "fill_replay_buffer", "episode_frame", "dataset_frame"]

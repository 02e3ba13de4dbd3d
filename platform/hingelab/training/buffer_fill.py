"""Fill a stable-baselines3 replay buffer from MCAP episode datasets, in bulk.

``episodes.transitions.fill_replay_buffer`` adds one transition at a time through
``buffer.add`` (tens of microseconds each); here whole arrays are written into the
buffer's storage. SB3 buffers hold ``n_envs`` transitions per row and sample any
(row, env) pair below ``pos``, so:

* plain / Dict buffers: transitions fill rows ``n_envs`` at a time (a remainder of
  fewer than ``n_envs`` transitions is left out: it would leave empty slots that get
  sampled);
* HER buffers: relabelling needs whole episodes in order, so episodes are dealt to the
  env slots (the emptiest slot next) and each slot is written as its own stream with
  its episodes' start and length; slots shorter than the longest keep ``ep_length`` 0
  in their tail rows, which HER never samples.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hingelab.envs.rewards import LowLevelRewardConfig
from hingelab.episodes import schemas as S
from hingelab.episodes.dataset import Dataset
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.transitions import Transitions, concat_transitions, episode_transitions
from hingelab.errors import ConfigError


@dataclass
class PrefillStats:
    datasets: int
    episodes: int
    transitions: int  # added to the buffer
    read_s: float
    insert_s: float

    @property
    def transitions_per_s(self) -> float:
        return self.transitions / max(self.read_s + self.insert_s, 1e-9)


def read_transitions(roots, progress: bool = False) -> tuple[Transitions, int]:
    """All transitions of the datasets (``/step`` only), episode by episode; and the episode count."""
    parts, episodes = [], 0
    for root in roots:
        root = Path(root)
        if not root.exists():
            raise ConfigError(f"dataset {root} does not exist; "
                              "give a dataset folder (hingelab datasets info lists one)")
        dataset = Dataset(root)
        if len(dataset) == 0:
            raise DatasetError(f"dataset {root} has no finished episodes to learn from")
        for episode in dataset.iter_episodes(topics=[S.TOPIC_STEP], progress=progress):
            if S.TOPIC_STEP not in episode.topics or "reward" not in episode.topics[S.TOPIC_STEP]:
                raise DatasetError(f"{episode.path} has no learner transitions (/step with reward); "
                                   "record it with RecordingWrapper or a learner")
            parts.append(episode_transitions(episode, episodes))
            episodes += 1
    return concat_transitions(parts), episodes


def _check_shapes(buffer, transitions: Transitions) -> None:
    spaces = getattr(buffer.observation_space, "spaces", None)
    if spaces is not None:
        if not transitions.is_dict:
            raise ConfigError("the datasets hold flat observations but the learner needs goal (Dict) observations")
        for key, space in spaces.items():
            got = transitions.observations.get(key)
            if got is None or got.shape[1:] != space.shape:
                raise ConfigError(f"dataset observation {key!r} has shape {None if got is None else got.shape[1:]}, "
                                  f"the learner needs {space.shape}: the datasets are from another task")
    elif transitions.is_dict or transitions.observations.shape[1:] != buffer.observation_space.shape:
        raise ConfigError("the datasets' observations do not match the learner's observation space")
    if transitions.actions.shape[1:] != buffer.action_space.shape:
        raise ConfigError(f"dataset actions have shape {transitions.actions.shape[1:]}, the learner's "
                          f"{buffer.action_space.shape}: the datasets are from another task")


def _write_rows(buffer, rows: np.ndarray, slots: np.ndarray, tr: Transitions, idx: np.ndarray) -> None:
    """Write transitions ``idx`` to buffer (row, slot) pairs."""
    if tr.is_dict:
        for key in buffer.observations:
            buffer.observations[key][rows, slots] = tr.observations[key][idx]
            buffer.next_observations[key][rows, slots] = tr.next_observations[key][idx]
    else:
        buffer.observations[rows, slots] = tr.observations[idx]
        buffer.next_observations[rows, slots] = tr.next_observations[idx]
    buffer.actions[rows, slots] = tr.actions[idx]
    buffer.rewards[rows, slots] = tr.rewards[idx]
    done = tr.terminated[idx] | tr.truncated[idx]
    buffer.dones[rows, slots] = done
    if getattr(buffer, "handle_timeout_termination", False):
        buffer.timeouts[rows, slots] = tr.truncated[idx] & ~tr.terminated[idx]


def insert_transitions(buffer, transitions: Transitions) -> int:
    """Bulk-write into an empty-or-partly-filled SB3 buffer from its ``pos``; returns transitions added."""
    _check_shapes(buffer, transitions)
    n_envs = buffer.n_envs
    if hasattr(buffer, "ep_length"):  # HerReplayBuffer
        return _insert_her(buffer, transitions)
    rows_needed = len(transitions) // n_envs
    space = buffer.buffer_size - buffer.pos
    if rows_needed > space:
        raise ConfigError(f"the datasets hold {len(transitions)} transitions, the replay buffer has room for "
                          f"{space * n_envs}; raise buffer_size or pre-fill from fewer datasets")
    idx = np.arange(rows_needed * n_envs)
    rows = buffer.pos + idx // n_envs
    _write_rows(buffer, rows, idx % n_envs, transitions, idx)
    buffer.pos += rows_needed
    buffer.full = buffer.full or buffer.pos == buffer.buffer_size
    buffer.pos %= buffer.buffer_size
    return len(idx)


def _insert_her(buffer, tr: Transitions) -> int:
    n_envs = buffer.n_envs
    starts = np.flatnonzero(np.r_[True, tr.episode_index[1:] != tr.episode_index[:-1]])
    ends = np.r_[starts[1:], len(tr)]
    fill = np.zeros(n_envs, dtype=np.int64)
    placements = []  # (slot, first row, episode start, episode end)
    for s, e in zip(starts, ends):
        slot = int(np.argmin(fill))
        placements.append((slot, buffer.pos + fill[slot], s, e))
        fill[slot] += e - s
    if buffer.pos + fill.max() > buffer.buffer_size:
        raise ConfigError(f"the datasets' episodes need {fill.max()} buffer rows, the replay buffer has "
                          f"{buffer.buffer_size - buffer.pos}; raise buffer_size or pre-fill from fewer datasets")
    for slot, row0, s, e in placements:
        idx = np.arange(s, e)
        rows = row0 + np.arange(e - s)
        _write_rows(buffer, rows, np.full(len(idx), slot), tr, idx)
        buffer.ep_start[rows, slot] = row0
        buffer.ep_length[rows, slot] = e - s
        if buffer.copy_info_dict:
            for j, row in enumerate(rows):
                buffer.infos[row, slot] = {k: float(v[s + j]) for k, v in tr.infos.items()}
    buffer.pos += int(fill.max())
    buffer.full = buffer.full or buffer.pos == buffer.buffer_size
    buffer.pos %= buffer.buffer_size
    buffer._current_ep_start[:] = buffer.pos
    return int(fill.sum())


def relabel_rewards(transitions: Transitions, goal_env) -> Transitions:
    """The learner's own rewards for recorded transitions: ``goal_env.compute_reward`` on the
    recorded goals and the recorded goal-free effort. A dataset recorded with another reward
    setting (the effort term on or off, other weights) then trains this run with this run's
    reward: from the unweighted ``tool_motion_m`` and ``finger_speed`` where the dataset has
    them; datasets recorded before those were can give only their ``effort`` as recorded, so
    they are refused for a run whose effort weights are not the defaults it was recorded with."""
    if not transitions.is_dict:
        raise ConfigError("reward relabelling needs goal (Dict) observations")
    config = getattr(goal_env, "reward_config", None)
    uses_effort = getattr(config, "use_effort", False)
    infos = transitions.infos
    unweighted = "tool_motion_m" in infos and "finger_speed" in infos
    if uses_effort and not unweighted:
        if "effort" not in infos:
            raise DatasetError("the datasets do not record the effort term (info.effort) that this run's reward "
                               "needs; record them with RecordingWrapper, or train with --no-effort")
        default = LowLevelRewardConfig()
        if (config.c2, config.c3) != (default.c2, default.c3):
            raise DatasetError(f"the datasets record the effort only as weighted when recorded (c2 {default.c2}, "
                               f"c3 {default.c3}), not the tool motion and finger speed that this run's weights "
                               f"(c2 {config.c2}, c3 {config.c3}) need; re-record them with this hingelab")
    # one info dict of arrays: compute_reward reads the whole batch at once
    if uses_effort and getattr(config, "c4", 0) > 0 and not (unweighted and "tool_drift_m" in infos):
        raise DatasetError("this run's drift term (--drift-weight) needs the tool drift, tool motion and finger "
                           "speed per step (info.tool_drift_m, info.tool_motion_m, info.finger_speed), which these "
                           "datasets do not record; re-record them with this hingelab, or train without it")
    if unweighted:
        info = {"tool_motion_m": infos["tool_motion_m"], "finger_speed": infos["finger_speed"]}
        if "tool_drift_m" in infos:
            info["tool_drift_m"] = infos["tool_drift_m"]
    else:
        info = {"effort": infos.get("effort", np.zeros(len(transitions)))}
    transitions.rewards = np.asarray(goal_env.compute_reward(transitions.next_observations["achieved_goal"],
                                                             transitions.observations["desired_goal"], info),
                                     dtype=np.float32)
    return transitions


def prefill_replay_buffer(buffer, roots, progress: bool = False, goal_env=None) -> PrefillStats:
    """Read the datasets and write their transitions into ``buffer``; timings for the report.

    ``goal_env``: relabel the rewards with this env's ``compute_reward`` (``relabel_rewards``).
    """
    roots = list(roots)
    t0 = time.perf_counter()
    transitions, episodes = read_transitions(roots, progress=progress)
    return fill_from_transitions(buffer, transitions, episodes, len(roots), time.perf_counter() - t0, goal_env)


def fill_from_transitions(buffer, transitions: Transitions, episodes: int, datasets: int, read_s: float,
                          goal_env=None) -> PrefillStats:
    """``prefill_replay_buffer`` for transitions already read (``read_s``: what reading them took)."""
    t0 = time.perf_counter()
    if goal_env is not None:
        transitions = relabel_rewards(transitions, goal_env)
    t1 = time.perf_counter()
    added = insert_transitions(buffer, transitions)
    t2 = time.perf_counter()
    return PrefillStats(datasets, episodes, added, read_s + t1 - t0, t2 - t1)

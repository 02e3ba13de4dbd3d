"""An ``Episode`` (numpy arrays per MCAP topic) -> the per-step series the views draw.

Pure numpy, no Rerun: ``episode_series(episode)`` returns one ``Series`` per entity
(see ``entities.py``), each with one row per step and the step's simulated log time.
The loggers send these as columns (one ``send_columns`` per entity), and a dataset
view concatenates the same series of many episodes before sending them.

Topics an episode lacks (a source without clouds, without a latent, ...) give no
series: the views simply stay empty for them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hingelab.episodes import Episode
from hingelab.episodes import schemas as S
from hingelab.viewers import entities as E

# kinds of series, i.e. which Rerun archetype a series becomes
POINTS3D = "points3d"  # values (T, N, 3): N points per step
POINTS2D = "points2d"  # values (T, N, 2)
SCALARS = "scalars"  # values (T,) or (T, K): K series on one entity
TRANSFORM = "transform"  # values (T, 7): translation (3) + quaternion x, y, z, w (4)
TEXT = "text"  # values (T,) str: a TextLog row per event (only at the event steps)


@dataclass
class Series:
    """One entity's rows: ``values`` (T, ...) at steps ``step`` (T,) and log times ``time_ns`` (T,).

    names: labels of the K scalar series (``SCALARS`` with values (T, K)), or of the N points.
    """

    entity: str
    kind: str
    values: np.ndarray
    step: np.ndarray
    time_ns: np.ndarray
    names: tuple[str, ...] = field(default=())

    def __len__(self) -> int:
        return len(self.values)


def _rows(topic_fields: dict[str, np.ndarray], name: str) -> np.ndarray | None:
    value = topic_fields.get(name)
    return None if value is None else np.asarray(value)


def _series(entity: str, kind: str, values, times: np.ndarray, names=()) -> Series:
    values = np.asarray(values)
    return Series(entity, kind, values, np.arange(len(values), dtype=np.int64),
                  np.asarray(times, dtype=np.int64), tuple(names))


def _xyzw(quaternion: np.ndarray) -> np.ndarray:
    """The contract stores x, y, z, w already (hand_base); normalize for the viewer."""
    norm = np.linalg.norm(quaternion, axis=-1, keepdims=True)
    return np.where(norm > 0, quaternion / np.where(norm > 0, norm, 1.0), [0.0, 0.0, 0.0, 1.0])


def step_outcome(episode: Episode) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(step log times (T,) ns, success (T,) 0/1, attempt (T,)) of an episode.

    success per step is ``/step`` info ``is_success`` when recorded; otherwise 0 and, at
    the last step, the episode's ``success`` fact. attempt per step is info ``attempt``
    when recorded, otherwise the episode's ``attempt`` fact at every step.
    """
    meta = episode.metadata
    step = episode.topics.get(S.TOPIC_STEP)
    if step is None:  # no learner records: use any per-step topic's times
        any_topic = next((v for t, v in episode.topics.items() if "log_time_ns" in v), None)
        times = np.zeros(0, np.int64) if any_topic is None else any_topic["log_time_ns"]
        step = {"log_time_ns": times}
    times = np.asarray(step["log_time_ns"], dtype=np.int64)
    n = len(times)
    success = _rows(step, "info.is_success")
    if success is None:
        success = np.zeros(n)
        if n:
            success[-1] = float(bool(meta.get(S.KEY_SUCCESS, False)))
    attempt = _rows(step, "info.attempt")
    if attempt is None:
        attempt = np.full(n, float(meta.get(S.KEY_ATTEMPT, 1) or 1))
    return times, np.asarray(success, float).reshape(n), np.asarray(attempt, float).reshape(n)


def outcome_events(episode: Episode) -> Series:
    """Text markers: each attempt after the first where it starts, and the outcome at the last step."""
    times, success, attempt = step_outcome(episode)
    steps, texts = [], []
    for k in np.flatnonzero(np.diff(attempt) > 0) + 1:
        steps.append(int(k))
        texts.append(f"attempt {int(attempt[k])}")
    if len(times):
        meta = episode.metadata
        if meta.get(S.KEY_SUCCESS, False):
            texts.append("success")
        else:
            reason = meta.get(S.KEY_FAILURE_REASON) or "unknown reason"
            texts.append(f"failure: {reason}")
        steps.append(len(times) - 1)
    steps_array = np.asarray(steps, dtype=np.int64)
    return Series(E.EVENTS, TEXT, np.asarray(texts, dtype=object), steps_array,
                  times[steps_array] if len(times) else np.zeros(0, np.int64))


def episode_series(episode: Episode, with_clouds: bool = True) -> list[Series]:
    """Every per-step series of ``episode`` the views draw (see the module docstring)."""
    topics = episode.topics
    out: list[Series] = []
    if with_clouds and S.TOPIC_POINTS in topics:
        clouds = topics[S.TOPIC_POINTS]
        out.append(_series(E.TOOL_CLOUD, POINTS3D, clouds["points"], clouds["log_time_ns"]))
    if S.TOPIC_TOOL_POSE in topics:
        pose = topics[S.TOPIC_TOOL_POSE]
        values = np.concatenate([pose["position"], _xyzw(pose["orientation"])], axis=1)
        out.append(_series(E.TOOL_FRAME, TRANSFORM, values, pose["log_time_ns"]))
    privileged = topics.get(S.TOPIC_PRIVILEGED, {})
    if "tip_a" in privileged and "tip_b" in privileged:
        tips = np.stack([privileged["tip_a"], privileged["tip_b"]], axis=1)
        out.append(_series(E.TIPS, POINTS3D, tips, privileged["log_time_ns"], names=("tip a", "tip b")))
    if "hinge_angle" in privileged:
        out.append(_series(E.HINGE_ANGLE, SCALARS, privileged["hinge_angle"], privileged["log_time_ns"],
                           names=("hinge angle (rad)",)))
    for topic, entity, label in ((S.TOPIC_OBJECT, E.OBJECT, "object"), (S.TOPIC_TARGET, E.TARGET, "target")):
        if topic in topics:
            position = topics[topic]["position"]
            out.append(_series(entity, POINTS3D, position[:, None, :], topics[topic]["log_time_ns"], names=(label,)))
    if S.TOPIC_JOINTS in topics:
        joints = topics[S.TOPIC_JOINTS]
        names = episode.metadata.get(S.KEY_JOINT_NAMES) or [f"joint {i}" for i in range(joints["position"].shape[1])]
        out.append(_series(E.HAND_JOINTS, SCALARS, joints["position"], joints["log_time_ns"], names=names))
    latent = topics.get(S.TOPIC_LATENT, {})
    for name, entity in (("z", E.LATENT_Z), ("z_smoothed", E.LATENT_Z_SMOOTHED)):
        if name in latent:
            out.append(_series(entity, SCALARS, latent[name], latent["log_time_ns"],
                               names=(f"{name}[0]", f"{name}[1]")))
    if "z" in latent:
        out.append(_series(E.PLANE_Z, POINTS2D, latent["z"][:, None, :], latent["log_time_ns"], names=("z",)))
    goal = topics.get(S.TOPIC_GOAL, {})
    if "z_goal" in goal:
        out.append(_series(E.LATENT_Z_GOAL, SCALARS, goal["z_goal"], goal["log_time_ns"],
                           names=("z_goal[0]", "z_goal[1]")))
        out.append(_series(E.PLANE_Z_GOAL, POINTS2D, goal["z_goal"][:, None, :], goal["log_time_ns"],
                           names=("z_goal",)))
    reward = topics.get(S.TOPIC_REWARD, {})
    for name, values in reward.items():
        if name != "log_time_ns":
            # a term the reset's message lacks (drift, in low-level episodes recorded before it was added
            # there) has fewer rows than the topic: they are its last messages'
            times = reward["log_time_ns"][len(reward["log_time_ns"]) - len(values):]
            out.append(_series(f"{E.REWARD}/{name}", SCALARS, values, times, names=(name,)))
    times, success, attempt = step_outcome(episode)
    out.append(_series(E.SUCCESS, SCALARS, success, times, names=("success",)))
    out.append(_series(E.ATTEMPT, SCALARS, attempt, times, names=("attempt",)))
    out.append(outcome_events(episode))
    return out


def episode_facts_markdown(episode: Episode) -> str:
    """The episode's metadata as a markdown table (for the facts panel)."""
    meta = episode.metadata
    keys = [S.KEY_EPISODE_ID, S.KEY_SOURCE, S.KEY_TASK, S.KEY_OBJECT, S.KEY_SEED, S.KEY_ATTEMPT,
            S.KEY_LENGTH, S.KEY_RETURN, S.KEY_SUCCESS, S.KEY_FAILURE_REASON, S.KEY_ACTION_LEVEL]
    lines = [f"# {episode.path.name}", "", "| fact | value |", "|---|---|"]
    lines += [f"| {key} | {meta[key]} |" for key in keys if meta.get(key) not in (None, "")]
    return "\n".join(lines) + "\n"


def latent_trajectory(episode: Episode) -> np.ndarray | None:
    """(T, 2) latent z over the episode, or None without a latent."""
    latent = episode.topics.get(S.TOPIC_LATENT, {})
    return latent.get("z")


def tip_midpoints(episode: Episode) -> np.ndarray | None:
    """(T, 3) midpoint of the two tweezer tips, metres, hand_base, or None."""
    privileged = episode.topics.get(S.TOPIC_PRIVILEGED, {})
    if "tip_a" not in privileged or "tip_b" not in privileged:
        return None
    return 0.5 * (privileged["tip_a"] + privileged["tip_b"])


__all__ = ["Series", "episode_series", "step_outcome", "outcome_events", "episode_facts_markdown",
           "latent_trajectory", "tip_midpoints", "POINTS3D", "POINTS2D", "SCALARS", "TRANSFORM", "TEXT"]

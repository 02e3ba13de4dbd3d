"""A trial's frames (``hingelab trial``, sources ``stand_in`` and ``real``) built from the topics it records.

A trial drives a robot, not a gymnasium env: there is no ``env.step`` and so no ``/step``
transition (``robot/trial.py`` logs the controller's inputs and outputs as topics). Its frames
are rebuilt here as ToolPick-v0 transitions, one per high-level action (``/action``): frame k's
observation is what the controller gave the high-level policy at that control period
(``robot/controller.py``), from the messages logged at the action's log time:

- the tool pose from ``/tool/pose`` (registration: position, m; orientation to extrinsic xyz
  Euler angles, rad), smoothed as the controller smooths it (``s <- alpha x + (1 - alpha) s``,
  alpha 0.9, from the first frame);
- z_bar (``/tool/latent`` ``z_smoothed``), the object's centre (``/object/position``) and the
  target (``/target/position``), all in hand_base;

the action is the high level's (5,) action in [-1, 1]; the reward is NaN (a trial has no
reward: the format module decides what to do with it); the last frame is terminated when the
trial succeeded (or lost the tool, as the env terminates), truncated otherwise. The 14-D
observation is ToolPick-v0's without the object's extent (``/object/estimate`` is not read).

A control period the camera gave no cloud for logs no action and is not a frame (the trial ends
there). An action whose log time lacks one of the other topics is one ``DatasetError`` naming the
file and the topic.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from hingelab.episodes import schemas as S
from hingelab.episodes.errors import DatasetError
from hingelab.tasks import TOOL_STATE_ALPHA as ALPHA

TRIAL_SOURCES = ("stand_in", "real")
# topic -> field: what a trial's frame is made of (the /action message is the frame)
TRIAL_TOPICS = {S.TOPIC_ACTION: "values", S.TOPIC_TOOL_POSE: "position", S.TOPIC_LATENT: "z_smoothed",
                S.TOPIC_OBJECT: "position", S.TOPIC_TARGET: "position"}
OBSERVATION_DIM = 14
ACTION_DIM = 5
TERMINAL_FAILURES = ("tool_drop",)  # failure reasons the env terminates on (others truncate)


def is_trial(channels, metadata: dict) -> bool:
    """A file without ``/step`` that holds a trial's topics (``channels``: its topic names)."""
    return (S.TOPIC_STEP not in channels and metadata.get(S.KEY_SOURCE) in TRIAL_SOURCES
            and all(topic in channels for topic in TRIAL_TOPICS))


def trial_fields() -> dict:
    """The /step fields a trial's frames have: {name: (numpy dtype string, shape)}."""
    return {"observation": ("<f8", (OBSERVATION_DIM,)), "action": ("<f8", (ACTION_DIM,)), "reward": ("<f8", ()),
            "terminated": ("|b1", ()), "truncated": ("|b1", ())}


def _at(episode, topic: str, name: str, times: np.ndarray) -> np.ndarray:
    fields = episode.topics[topic]
    logged = np.asarray(fields["log_time_ns"], dtype=np.int64)
    i = np.clip(np.searchsorted(logged, times), 0, max(len(logged) - 1, 0))
    if len(logged) == 0 or (logged[i] != times).any():
        missing = int((len(logged) == 0) or (logged[i] != times).sum())
        raise DatasetError(f"{episode.path}: {missing} of its {len(times)} high-level actions have no {topic} message "
                           "at their log time; a trial's frame needs one (re-record the trial)")
    return np.asarray(fields[name], dtype=np.float64)[i]


def smoothed_pose(pose: np.ndarray) -> np.ndarray:
    """The controller's smoothing of the tool pose (T, 6): s <- alpha x + (1 - alpha) s, from the first."""
    out = np.empty_like(pose)
    out[0] = pose[0]
    for k in range(1, len(pose)):
        out[k] = ALPHA * pose[k] + (1 - ALPHA) * out[k - 1]
    return out


def trial_step(episode) -> dict:
    """The trial's frames as ``/step`` arrays (observation, action, reward, terminated, truncated, log_time_ns)."""
    times = np.asarray(episode.topics[S.TOPIC_ACTION]["log_time_ns"], dtype=np.int64)
    n = len(times)
    if n == 0:
        return {}
    position = _at(episode, S.TOPIC_TOOL_POSE, "position", times)
    quaternion = _at(episode, S.TOPIC_TOOL_POSE, "orientation", times)  # x, y, z, w
    euler = Rotation.from_quat(quaternion).as_euler("xyz")
    pose = smoothed_pose(np.concatenate([position, euler], axis=1))
    observation = np.concatenate([pose, _at(episode, S.TOPIC_LATENT, "z_smoothed", times),
                                  _at(episode, S.TOPIC_OBJECT, "position", times),
                                  _at(episode, S.TOPIC_TARGET, "position", times)], axis=1)
    meta = episode.metadata
    success = bool(meta.get(S.KEY_SUCCESS, False))
    terminated, truncated = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    if success or meta.get(S.KEY_FAILURE_REASON) in TERMINAL_FAILURES:
        terminated[-1] = True
    else:
        truncated[-1] = True
    return {"observation": observation, "action": np.asarray(episode.topics[S.TOPIC_ACTION]["values"], np.float64),
            "reward": np.full(n, np.nan), "terminated": terminated, "truncated": truncated, "log_time_ns": times}


__all__ = ["TRIAL_SOURCES", "TRIAL_TOPICS", "is_trial", "smoothed_pose", "trial_fields", "trial_step"]

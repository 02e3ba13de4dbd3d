"""``RecordingWrapper``: every episode of either env becomes one MCAP episode in a dataset.

Per step it writes what ``env.unwrapped.last_record`` holds (the tool cloud, registered
tool pose, hand joints, latents, goal, action, reward terms, object and target, the
privileged simulator state alongside, and with a camera object estimator its estimate, the
truth and the object's visible points) plus the learners' transition (observation before
the action, the action executed, reward, terminated, truncated, info scalars). The
episode file is finished when the episode ends; an episode cut short by ``reset`` or
``close`` is discarded (a half episode is not data), and one whose step raised keeps its
``.partial`` file for ``hingelab datasets recover``.

The episode's ``success`` is the env's one verdict, ``info["is_success"]`` of the last step,
and ``success_verdict`` names it (``success_verdict(env)``; written at open, so a cut-off
file says it too). A secondary verdict the env reports (ToolShape-v0's
``info["last_step_success"]``) is recorded under its own key, never as ``success``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np

from hingelab.episodes import EpisodeWriter
from hingelab.episodes import schemas as S
from hingelab.episodes.card import load_card
from hingelab.json_text import strict_dumps
from hingelab.sim import names

SVH_JOINTS = list(names.HAND_ACTUATORS)


def _xyzw(quat_wxyz: np.ndarray) -> np.ndarray:
    w, x, y, z = quat_wxyz
    return np.array([x, y, z, w])


def privileged_fields(state) -> dict:
    """``PrivilegedState`` -> the ``/sim/privileged`` fields of the episode contract (hand_base frame)."""
    return {
        "hinge_angle": state.hinge_angle,
        "tool_position": state.tool_pos_hand,
        "tool_orientation": _xyzw(state.tool_quat_hand),
        "tip_a": state.tip_a_hand,
        "tip_b": state.tip_b_hand,
        "object_position": np.nan_to_num(state.object_pos_hand, nan=0.0),
        "object_orientation": _xyzw(np.nan_to_num(state.object_quat_world, nan=0.0)),
        "contact_count": state.n_contacts,
        "table_collision": state.table_collision,
    }


def _scalars(info: dict) -> dict[str, float]:
    out = {}
    for key, value in info.items():
        if isinstance(value, (bool, int, float, np.floating, np.integer, np.bool_)):
            out[key] = float(value)
    return out


def reward_metadata(env: gym.Env) -> dict[str, str]:
    """The env's reward config as episode metadata (JSON), so that a dataset says which reward (its
    weights, and for ToolPick-v0 its mode) its rewards are; {} for an env without one."""
    config = getattr(env.unwrapped, "reward_config", None)
    if config is None or not dataclasses.is_dataclass(config):
        return {}
    text = strict_dumps(dataclasses.asdict(config), "the episode's reward config", sort_keys=True)
    return {S.KEY_REWARD_CONFIG: text}


def object_metadata(record: dict | None) -> dict:
    """The episode facts of a drawn object (``record``: ``ToolPickEnv.object_record``, a family's draw): its
    kind, its draw as JSON and its size, which replaces the size cap; {} for a fixed object (None)."""
    if record is None:
        return {}
    draw = strict_dumps(record, "the episode's object draw", sort_keys=True)
    return {S.KEY_OBJECT_KIND: record["kind"], S.KEY_OBJECT_DRAW: draw,
            "object_size": record["size_m"]}


def object_perception_metadata(env) -> dict:
    """The object estimator an env (or robot) ran, and the fitted camera error it drew (``object_noise``) with its
    model file's hash, as episode facts; {} for the truth with the Gaussian (the default, as episodes recorded
    before there was a choice)."""
    name = getattr(env, "object_perception", "truth")
    facts = {} if name == "truth" else {S.KEY_OBJECT_PERCEPTION: name}
    fitted = getattr(env, "object_fitted", None)
    if fitted is not None:
        facts.update({S.KEY_OBJECT_NOISE: env.object_noise, S.KEY_OBJECT_NOISE_MODEL: fitted.model.sha256})
    return facts


def success_verdict(env: gym.Env) -> str | None:
    """The name of the verdict ``info["is_success"]`` gives (a key of ``schemas.SUCCESS_VERDICTS``).

    An env says it with its ``success_verdict`` attribute (ToolShape-v0: ``"settled_0.5s"``;
    ToolPick-v0: ``"object_within_1cm"`` at its default success radius). None for an env that
    does not say.
    """
    return getattr(env.unwrapped, "success_verdict", None)


class RecordingWrapper(gym.Wrapper):
    """Writes each episode of ``env`` into ``dataset_dir`` (made by ``create_dataset``)."""

    def __init__(self, env: gym.Env, dataset_dir, source: str, task: str | None = None,
                 object_name: str = "", action_level: str = "", extra_metadata: dict | None = None):
        super().__init__(env)
        self.dataset_dir = Path(dataset_dir)
        load_card(self.dataset_dir)  # a clear error now, not at the first episode's end
        self.source = source
        self.task = task or (env.spec.id if env.spec else type(env.unwrapped).__name__)
        self.object_name = object_name
        self.action_level = action_level
        self.extra_metadata = extra_metadata or {}
        self.success_verdict = success_verdict(env)
        self.writer: EpisodeWriter | None = None
        self.episode_seed: int | None = None
        self.last_obs = None
        self.paths: list[Path] = []

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self._discard()
        obs, info = self.env.reset(seed=seed, options=options)
        self.episode_seed = seed
        self.writer = EpisodeWriter(self.dataset_dir, source=self.source, task=self.task, object=self.object_name,
                                    seed=seed, action_level=self.action_level, joint_names=SVH_JOINTS,
                                    extra_metadata={S.KEY_SUCCESS_VERDICT: self.success_verdict,
                                                    **reward_metadata(self.env), **self.extra_metadata})
        self.writer.facts.update(object_metadata(getattr(self.env.unwrapped, "object_record", None)))
        self.writer.facts.update(object_perception_metadata(self.env.unwrapped))
        self.writer.open()
        self._write(obs_before=None, action=None, reward=0.0, terminated=False, truncated=False, info=info)
        self.last_obs = obs
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        executed = info.get("executed_action", action)
        self._write(self.last_obs, executed, reward, terminated, truncated, info)
        self.last_obs = obs
        if terminated or truncated:
            self._finish(obs, info)
        return obs, reward, terminated, truncated, info

    def close(self):
        self._discard()
        super().close()

    # ------------------------------------------------------------------ parts
    def _write(self, obs_before, action, reward, terminated, truncated, info) -> None:
        unwrapped = self.env.unwrapped
        record = unwrapped.last_record
        sim = unwrapped.sim
        rotation = record["tool_rotation"]
        quat = _rotation_to_xyzw(rotation)
        transition = None
        if obs_before is not None:
            transition = {"observation": obs_before, "action": np.asarray(action, float), "reward": float(reward),
                          "terminated": bool(terminated), "truncated": bool(truncated), "info": _scalars(info)}
        self.writer.write_step(
            record["privileged"].time,
            points_hand=record["cloud"],
            tool_pose_hand=(record["tool_position"], quat),
            joint_position=sim.hand.q(sim.data), joint_velocity=sim.hand.qdot(sim.data),
            latent_z=record["latent_z"], latent_z_smoothed=record["latent_z_smoothed"],
            action=None if action is None else np.asarray(action, float),
            goal_z=record["goal_z"], reward_terms=record["reward_terms"],
            object_position_hand=record["object_position_hand"], target_position_hand=record["target_position_hand"],
            privileged=privileged_fields(record["privileged"]), transition=transition,
            platform_hand=platform_pose(record.get("platform_hand")),
        )
        if record.get("object_estimate") is not None:  # the camera's object estimate beside the truth
            self.writer.write_object_estimate(record["privileged"].time, **record["object_estimate"])

    def _finish(self, final_obs, info: dict) -> None:
        success = bool(info.get("is_success", 0.0))  # the env's one verdict
        reason = None if success else info.get("failure_reason", "timeout")
        secondary = {}
        if "last_step_success" in info:  # ToolShape-v0's one-frame verdict: its own key
            secondary[S.KEY_LAST_STEP_SUCCESS] = bool(info["last_step_success"])
        self.writer.write_final_observation(final_obs)
        self.writer.set_outcome(success, failure_reason=reason, attempt=int(info.get("attempt", 1)),
                                first_attempt_success=bool(info.get("first_attempt_success", success)), **secondary)
        self.paths.append(self.writer.close())
        self.writer = None

    def _discard(self) -> None:
        if self.writer is not None and not self.writer.closed:
            self.writer.abort()
        self.writer = None


def platform_pose(platform) -> tuple | None:
    """(centre, rotation (3, 3), size) -> (centre, quaternion xyzw, size) for the writer's /scene, or None."""
    if platform is None:
        return None
    centre, rotation, size = platform
    return centre, _rotation_to_xyzw(rotation), size


def _rotation_to_xyzw(rotation: np.ndarray) -> np.ndarray:
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.asarray(rotation, float).ravel())
    return _xyzw(quat)

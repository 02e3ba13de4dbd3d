"""The sim core: a scene stepped at the control rate with the paper's two controllers.

One ``step`` is one 20 Hz control period (``n_substeps`` physics steps):

* hand: relative joint targets, ``target = q_now + action`` (9 primary joints, rad),
  clipped to the servo ranges; the 11 coupled joints follow by equality constraints;
* arm (tool_pick only): a 3-D hand velocity (m/s, arm base frame) through the damped
  Jacobian pseudoinverse (``ArmVelocityController``);
* privileged: a direct hinge target (rad) on the ``tool_hinge_cmd`` servo, for the
  heuristic controller; off (zero gain) unless commanded.

A diverging simulation (NaN state or MuJoCo's bad-acceleration warning) ends the episode
with ``StepResult.diverged`` instead of raising; stepping again needs ``reset``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from hingelab.errors import ConfigError
from hingelab.sim import names
from hingelab.sim.arm_control import ArmVelocityController
from hingelab.sim.delay import DelayLine
from hingelab.sim.hand import HandActuators
from hingelab.sim.objects import TRAINING_OBJECT, ObjectSpec
from hingelab.sim.privileged import PrivilegedReader, PrivilegedState
from hingelab.sim.randomization import DomainRandomizer, EpisodeRandomization, RandomizationConfig
from hingelab.sim.scene import load_scene

CONTROL_HZ = 20.0
HINGE_SERVO_KP = 2.0  # N m / rad when the privileged hinge command is on
MAX_HAND_SPEED = 0.5  # m/s: commanded hand velocities beyond this are refused as invalid
_INSTABILITY_WARNINGS = np.array([int(w) for w in (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
                                                   mujoco.mjtWarning.mjWARN_BADQACC)])


@dataclass(frozen=True)
class StepResult:
    state: PrivilegedState
    diverged: bool
    reason: str = ""  # why it diverged


class SimCore:
    """Load ``scene`` (``tool_shape`` or ``tool_pick``) and step it at ``control_hz``."""

    def __init__(self, scene: str = "tool_pick", obj: ObjectSpec | None = None,
                 randomization: RandomizationConfig | None = None, control_hz: float = CONTROL_HZ,
                 seed: int | None = None, camera=None):
        self.scene = scene
        self.camera = camera  # rig_camera.DepthIntrinsics or None
        self.randomization = randomization or RandomizationConfig(enabled=False)
        self.control_dt = 1.0 / control_hz
        self._load(obj)
        self.rng = np.random.default_rng(seed)
        self.episode: EpisodeRandomization | None = None
        self.hand_delay = DelayLine(self.control_dt, 0.150)
        self.diverged = False
        self._warnings_at_reset = 0

    def _load(self, obj: ObjectSpec | None) -> None:
        """Compile the scene with ``obj`` and make everything that holds the model's ids."""
        self.object = obj
        self.model = load_scene(self.scene, obj, self.camera)
        self.data = mujoco.MjData(self.model)
        self.n_substeps = int(round(self.control_dt / self.model.opt.timestep))
        if not np.isclose(self.n_substeps * self.model.opt.timestep, self.control_dt):
            raise ConfigError(f"control rate {1.0 / self.control_dt:g} Hz is not a multiple of the physics step "
                              f"{self.model.opt.timestep} s")
        self.hand = HandActuators(self.model)
        self.has_arm = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, names.ARM_JOINTS[0]) >= 0
        self.arm = ArmVelocityController(self.model) if self.has_arm else None
        self.reader = PrivilegedReader(self.model)
        self.randomizer = DomainRandomizer(self.model, self.randomization)
        self.hinge_actuator = self.model.actuator(names.TOOL_HINGE_ACTUATOR).id
        self.key = self.model.key(names.GRASP_KEYFRAME).id

    def set_object(self, obj: ObjectSpec) -> None:
        """Rebuild the model and its data with ``obj`` (a family's next draw); ``reset`` next. Whatever holds
        the old ``model``, ``data`` or their geom ids (renderers, cached geoms) must be refreshed by its owner."""
        self._load(obj)
        self.episode = None
        self.diverged = False

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int | None = None, object_xy: np.ndarray | None = None) -> PrivilegedState:
        """Back to the ``grasp`` keyframe, with new randomization; returns the first state.

        ``object_xy``: where to put the object (world x, y in m; default: the keyframe's).
        """
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        m, d = self.model, self.data
        mujoco.mj_resetDataKeyframe(m, d, self.key)
        self._set_hinge_servo(None)
        self._rest_object(object_xy)
        self.episode = self.randomizer.sample(self.rng)
        self.randomizer.apply(self.episode)
        mujoco.mj_forward(m, d)
        if self.arm is not None:
            self.arm.reset(d)
        self.diverged = False
        self._warnings_at_reset = self._instability_warnings()
        self.hand_delay.reset(self._hand_sample())
        return self.reader.read(d)

    def _rest_object(self, object_xy) -> None:
        """Object at ``object_xy`` (or the keyframe's x, y), resting upright on the platform."""
        body = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, names.OBJECT_BODY)
        if body < 0:
            return
        m = self.model
        platform = m.geom("platform").id
        surface = m.geom_pos[platform][2] + m.geom_size[platform][2]
        adr = m.jnt_qposadr[m.joint(names.OBJECT_FREE_JOINT).id]
        q = self.data.qpos
        if object_xy is not None:
            q[adr:adr + 2] = _checked("object position", object_xy, 2)
        obj = self.object or ObjectSpec(*TRAINING_OBJECT)
        q[adr + 2] = surface + obj.rest_height
        q[adr + 3:adr + 7] = (1, 0, 0, 0)

    # ------------------------------------------------------------------ control
    def step(self, hand_action: np.ndarray | None = None, arm_velocity: np.ndarray | None = None,
             hinge_target: float | None = None) -> StepResult:
        """Advance one control period. Inputs: see the module docstring; None holds the last command."""
        if self.diverged:
            raise ConfigError("the simulation diverged in this episode; call reset() before stepping again")
        d = self.data
        if hand_action is not None:
            action = _checked("hand action", hand_action, 9)
            target = self.hand.q(d) + action
            d.ctrl[self.hand.actuator_ids] = self.hand.clip_to_ctrl_range(target)
        if arm_velocity is not None:
            if self.arm is None:
                raise ConfigError(f"scene {self.scene!r} has no arm; arm velocities need tool_pick")
            velocity = _checked("arm velocity", arm_velocity, 3)
            if np.linalg.norm(velocity) > MAX_HAND_SPEED:
                raise ConfigError(f"arm velocity {np.linalg.norm(velocity):.3g} m/s exceeds "
                                  f"{MAX_HAND_SPEED} m/s; scale the command down")
            self.arm.command(d, velocity, self.control_dt)
        if hinge_target is not None:
            self._set_hinge_servo(float(_checked("hinge target", np.atleast_1d(hinge_target), 1)[0]))
        # one call for all substeps: the same state as n single calls, without n Python round trips
        mujoco.mj_step(self.model, d, nstep=self.n_substeps)
        # after mj_step, positions are new but derived quantities are one substep old
        mujoco.mj_kinematics(self.model, d)
        mujoco.mj_comPos(self.model, d)
        reason = self._divergence()
        if reason:
            self.diverged = True
        self.hand_delay.push(self._hand_sample())
        return StepResult(self.reader.read(d), bool(reason), reason)

    def set_hand_targets(self, targets: np.ndarray) -> None:
        """Absolute hand servo targets (9, rad), e.g. from the grasp synergy."""
        targets = _checked("hand targets", targets, 9)
        self.data.ctrl[self.hand.actuator_ids] = self.hand.clip_to_ctrl_range(targets)

    def release_hinge(self) -> None:
        """Turn the privileged hinge servo off again."""
        self._set_hinge_servo(None)

    def _set_hinge_servo(self, target: float | None) -> None:
        m = self.model
        kp = 0.0 if target is None else HINGE_SERVO_KP
        m.actuator_gainprm[self.hinge_actuator, 0] = kp
        m.actuator_biasprm[self.hinge_actuator, 1] = -kp
        if target is not None:
            low, high = m.actuator_ctrlrange[self.hinge_actuator]
            self.data.ctrl[self.hinge_actuator] = np.clip(target, low, high)

    # ------------------------------------------------------------------ state
    def _hand_sample(self) -> np.ndarray:
        """(18,): q (9, rad) then qdot (9, rad/s) of the primary hand joints."""
        return np.concatenate((self.hand.q(self.data), self.hand.qdot(self.data)))

    def hand_observation(self) -> tuple[np.ndarray, np.ndarray]:
        """(q, qdot) of the 9 primary hand joints as seen through this episode's sensor delay."""
        delay = self.episode.observation_delay_s if self.episode else 0.0
        sample = self.hand_delay.read(delay)
        return sample[:9], sample[9:]

    def privileged(self) -> PrivilegedState:
        return self.reader.read(self.data)

    def _instability_warnings(self) -> int:
        number = self.data.warning.number  # one array read (indexing the warning list per kind is slower)
        return int(number[_INSTABILITY_WARNINGS].sum())

    def _divergence(self) -> str:
        d = self.data
        if self._instability_warnings() > self._warnings_at_reset:
            # MuJoCo has already reset the state to the model's defaults: the episode is void
            return "MuJoCo found a NaN, Inf or huge position, velocity or acceleration"
        # one dot product per array: NaN or Inf anywhere makes it non-finite (overflow only past ~1e154)
        if not (math.isfinite(d.qpos @ d.qpos) and math.isfinite(d.qvel @ d.qvel)):
            return "NaN or Inf in the simulation state"
        return ""


def _checked(what: str, value, size: int) -> np.ndarray:
    """``value`` as a flat float array of ``size`` finite values; ConfigError otherwise."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 1:
        arr = arr.reshape(-1)
    if arr.shape != (size,):
        raise ConfigError(f"{what} must have {size} values, got shape {np.shape(value)}")
    # a finite sum of squares proves every value finite (NaN/Inf propagate); only a non-finite
    # one (a bad value, or an overflow past ~1e154) needs the element-wise test
    if not math.isfinite(arr @ arr) and not np.isfinite(arr).all():
        raise ConfigError(f"{what} contains NaN or Inf ({arr.tolist()}); check the policy's output")
    return arr

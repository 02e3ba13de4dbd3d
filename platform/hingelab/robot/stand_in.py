"""The MuJoCo stand-in of the rig behind the robot interface: ToolPick-v0's scene, seen by the depth camera.

Underneath is ``hingelab/ToolPick-v0`` with ``perception="camera"`` and domain randomization (so the
arm, hand, tool, object and the rendered, noisy depth frames are the envs' own), driven by raw
commands: the hand velocity and the hand's position targets go to the sim as they would go to a
real arm and hand (``ToolPickEnv.command_privileged`` without a hinge command: the fingers alone
move the tweezer). The env keeps its one verdict (object within 1 cm of the target), the attempts
and the failure reasons (``FailureReasonWrapper``); ``verdict()`` reports them.

What the stand-in reports as the object estimate (``object_perception``): by default (``"truth"``) the
object's centre (the middle of its resting height) and its bounding box, each with 2 mm noise; with an
estimator of ``hingelab.perception.object_estimate`` (``"centroid"``, the paper's, ``"ray_corrected"``,
``"primitive_fit"``) the env's estimate from the same depth frame as the tool's cloud
(``hingelab.perception.object_perception``): the last good one while the tool hides the object, None before
the first (the trial then ends, ``no_object_estimate``), with the frame's visible points and flag.

Latency: a rig's readings are old when the controller gets them (exposure, transfer, the cloud
pipeline). The stand-in delivers each reading ``latency_steps`` control periods late, drawn per
trial as the env's observation delay (0 to 150 ms, ``RandomizationConfig``) rounded to whole 50 ms
periods; the policies were trained under those delays and pick more often with them than without
(``analysis/stand-in-trials/README.md``).
"""

from __future__ import annotations

from collections import deque

import gymnasium as gym
import numpy as np

from hingelab.envs import TOOL_PICK_ID
from hingelab.perception.tool_perception import CALIBRATED, REFINED
from hingelab.robot.interface import RobotReadings, Verdict, register_robot
from hingelab.rollouts.high_level import FailureReasonWrapper
from hingelab.sim import names

OBJECT_NOISE_M = 0.002


class StandInRobot:
    source = "stand_in"
    arm_joint_names = names.ARM_JOINTS
    hand_joint_names = names.HAND_ACTUATORS

    def __init__(self, object: str = "sphere", size: float = 0.02, mass: float = 0.01, max_steps: int = 200,
                 randomize: bool = True, object_perception: str = "truth", hand_eye: str = CALIBRATED):
        self.env = FailureReasonWrapper(gym.make(TOOL_PICK_ID, object=object, size=size, mass=mass,
                                                 low_level="privileged", perception="camera", randomize=randomize,
                                                 max_episode_steps=max_steps,
                                                 object_perception=object_perception, hand_eye=hand_eye))
        self.object_perception = object_perception
        self.hand_eye = hand_eye
        self.pick = self.env.unwrapped
        self.sim = self.pick.sim
        self._arm_qpos = [self.sim.model.joint(j).qposadr[0] for j in names.ARM_JOINTS]
        self._arm_dof = [self.sim.model.joint(j).dofadr[0] for j in names.ARM_JOINTS]
        self._verdict: Verdict | None = None
        self.rng = np.random.default_rng()
        self.last_info: dict = {}
        self.latency_steps = 0
        self._readings: deque[RobotReadings] = deque(maxlen=8)

    def start_trial(self, seed: int) -> RobotReadings:
        _, info = self.env.reset(seed=seed)
        self.rng = np.random.default_rng([seed, 31])
        self.last_info = info
        self._verdict = Verdict(False, 1, False, False)
        episode = self.sim.episode
        self.latency_steps = int(round(episode.observation_delay_s / self.sim.control_dt)) if episode else 0
        self._readings.clear()
        return self._deliver(self._read())

    def command(self, hand_velocity: np.ndarray, hand_changes: np.ndarray) -> RobotReadings:
        rotation = self.sim.data.xmat[self.pick._hand_body].reshape(3, 3)
        targets = self.sim.hand.q(self.sim.data) + np.asarray(hand_changes, float)  # at the servo: its own position
        self.pick.command_privileged(rotation @ np.asarray(hand_velocity, float), None, targets)
        _, _, terminated, truncated, info = self.env.step(np.zeros(5))
        self.last_info = info
        success = bool(info["is_success"])
        self._verdict = Verdict(success, int(info["attempt"]), bool(info["first_attempt_success"]),
                                bool(terminated or truncated), None if success else info.get("failure_reason"))
        return self._deliver(self._read())

    def verdict(self) -> Verdict | None:
        return self._verdict

    def close(self) -> None:
        self.env.close()

    def _deliver(self, fresh: RobotReadings) -> RobotReadings:
        """The reading ``latency_steps`` periods old (the oldest one kept, early in a trial)."""
        self._readings.append(fresh)
        return self._readings[max(len(self._readings) - 1 - self.latency_steps, 0)]

    def _read(self) -> RobotReadings:
        data = self.sim.data
        q, qdot = self.sim.hand.q(data), self.sim.hand.qdot(data)  # as measured now; _deliver makes them late
        camera = self.pick.object_camera
        if camera is None:
            centre = self.pick.observed_object_centre() + self.rng.normal(0.0, OBJECT_NOISE_M, 3)
            extent = self.pick.observed_object_extent() + self.rng.normal(0.0, OBJECT_NOISE_M, 3)
            points, flag = None, None
        else:  # the env's estimate on this step's frame (world: the stand-in's base frame)
            centre = None if camera.estimate is None else camera.estimate.copy()
            extent = None if camera.extent is None else camera.extent.copy()
            points = None if camera.points is None else camera.points.copy()
            flag = camera.flag
        return RobotReadings(
            stamp_s=float(data.time), arm_position=data.qpos[self._arm_qpos].copy(),
            arm_velocity=data.qvel[self._arm_dof].copy(), hand_position=np.asarray(q, float).copy(),
            hand_velocity=np.asarray(qdot, float).copy(),
            hand_rotation=data.xmat[self.pick._hand_body].reshape(3, 3).copy(),
            hand_translation=data.xpos[self.pick._hand_body].copy(), frame=self.pick.perception.camera.frame,
            object_centre=centre, object_extent=extent, object_points=points, object_flag=flag)

    def episode_facts(self) -> dict:
        """Facts of this trial for its episode record: the hand-eye refinement's fit (``hand_eye="refined"``):
        how far it turned and moved the camera, the rms residual and the inlier share; the error drawn in the
        platform's height where the object's model is fitted (``object_support_error_mm``)."""
        object_camera = self.pick.object_camera
        support = {} if object_camera is None or object_camera.object_model is None else \
            {"object_support_error_mm": round(object_camera.support_error * 1e3, 3)}
        return {**self._hand_eye_facts(), **support}

    def _hand_eye_facts(self) -> dict:
        if self.hand_eye != REFINED:
            return {} if self.hand_eye == CALIBRATED else {"hand_eye": self.hand_eye}
        camera = self.pick.perception.camera
        refinement = camera.refinement
        if refinement is None:
            return {"hand_eye": self.hand_eye, "hand_eye_refined": False}
        corrected = camera.frame.camera_position
        believed = refinement.rotation.T @ (corrected - refinement.translation)
        return {"hand_eye": self.hand_eye, "hand_eye_refined": True,
                "hand_eye_angle_deg": round(refinement.angle_deg, 4),
                "hand_eye_camera_shift_mm": round(float(np.linalg.norm(corrected - believed)) * 1e3, 3),
                "hand_eye_rms_mm": round(refinement.rms_m * 1e3, 3),
                "hand_eye_inliers": round(refinement.inliers / refinement.n_source, 4)}

    def true_object_centre(self) -> np.ndarray:
        """The object's true centre now (world, m): what the episode records beside the estimate."""
        return self.pick.observed_object_centre()


register_robot("sim", lambda object, size, max_steps, object_perception="truth", hand_eye=CALIBRATED: StandInRobot(
    object, size, max_steps=max_steps, object_perception=object_perception, hand_eye=hand_eye))

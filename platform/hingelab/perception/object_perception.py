"""Where the object's position and extent come from: ``object_perception``, named in every episode.

* ``"truth"`` (the default): the object's true centre and bounding box; the env adds its 2 mm Gaussian noise;
* an estimator of ``hingelab.perception.object_estimate`` (``centroid``, the paper's; ``ray_corrected``;
  ``primitive_fit``): ``CameraObjectEstimate`` estimates the object from the depth camera's frame.

When: on every frame. The paper's rig runs its perception per camera frame (the tool's cloud at 20 Hz), the
object moves once it is grasped, and the policy observes the object at every step; the target (5 cm above the
object's start) is the first estimate's on the rig (``robot.controller``) and, in ToolPick-v0, as before.

Which frame: the one the tool's camera path rendered this step (``CameraClouds.frame`` and ``.geoms``): one
render per step, the same noisy depth, and the same believed camera pose (its calibration error), carried from
hand_base into the world with the hand's pose (the arm's forward kinematics on a rig), so that a calibration
error moves the tool's cloud and the object's estimate alike relative to the hand. It therefore needs
``perception="camera"``: with synthesized tool clouds there is no frame, and the env refuses the combination
(training without rendering is the fitted error model's job, not this one's).

A frame without an estimate (``ObjectEstimate.flag``: no object pixels, hidden by the tool, off the platform,
too few points) keeps the last good estimate: the tool hides the object while it grasps it, and the estimate
from before the grasp is the best there is. Until there has been one (``estimate`` None), the centre is the
platform's middle (``placeholder``) and the env ends the episode at its first step (failure reason
``no_object_estimate``), as a camera without a tool cloud ends it (``no_camera_cloud``).
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from hingelab.errors import ConfigError
from hingelab.perception.object_estimate import (
    ESTIMATORS,
    MODEL_ESTIMATORS,
    MaskErrors,
    ObjectCloudConfig,
    ObjectEstimate,
    estimate_object,
    object_cloud,
)
from hingelab.perception.object_model_fit import ObjectModel
from hingelab.perception.tool_perception import CameraClouds
from hingelab.sim import names
from hingelab.sim.object_render import platform_crop

TRUTH = "truth"
SUPPORT_ERROR_M = 0.002  # the platform's height as a rig knows it: uniform within +-2 mm per episode (chosen)
OBJECT_PERCEPTIONS = (TRUTH, *ESTIMATORS)


def check_object_perception(name: str) -> str:
    if name not in OBJECT_PERCEPTIONS:
        raise ConfigError(f"object perception {name!r} is unknown; choose one of {', '.join(OBJECT_PERCEPTIONS)}")
    return name


def check_object_perception_with(name: str, perception: str) -> str:
    """``name`` checked, and refused with synthesized tool clouds (an estimator reads the camera's frame)."""
    if check_object_perception(name) != TRUTH and perception != "camera":
        raise ConfigError(f"object perception {name!r} estimates the object from the depth camera's frame: it needs "
                          f"perception 'camera' (--perception camera), not {perception!r}")
    return name


class CameraObjectEstimate:
    """``new_episode(seed, model)``, then ``observe(camera, hand_rotation, hand_position)`` once per frame.

    After each frame: ``estimate`` (3,) and ``extent`` (3,), world, m, the last good ones (None before the
    first); ``fresh`` (this frame gave them); ``flag`` (why it did not); ``points`` (N, 3) world, m, this
    frame's visible points (None when flagged); ``n_points``. ``mask_errors``: the segmentation's errors,
    drawn per frame from the episode's own stream (the other draws of the env do not shift).
    ``support_error_m``: for an estimator that fits the object's model (``mesh_fit``), the platform's height
    that the model rests on is the simulator's plus an error drawn per episode, uniform within this (a rig
    knows its fixture's height from its calibration, to a millimetre or two; a stream of its own, so the
    mask errors' draws do not shift); recorded as ``support_error``."""

    def __init__(self, estimator: str, mask_errors: MaskErrors = MaskErrors(),
                 support_error_m: float = SUPPORT_ERROR_M):
        if check_object_perception(estimator) == TRUTH:
            raise ConfigError("CameraObjectEstimate needs an estimator, not 'truth'")
        if not support_error_m >= 0:
            raise ConfigError(f"the support height's error bound must be >= 0 m, not {support_error_m}")
        self.estimator, self.mask_errors, self.support_error_m = estimator, mask_errors, support_error_m
        self.support_error = 0.0  # m, this episode's draw
        self.rng = np.random.default_rng()
        self.config = ObjectCloudConfig()
        self.placeholder = np.zeros(3)
        self._object_geoms = np.zeros(0, int)
        self.object_model: ObjectModel | None = None  # the object's model, for an estimator that fits one
        self._exact_model: tuple[mujoco.MjModel, ObjectModel] | None = None  # sampled once per MjModel
        self._clear()

    def _clear(self) -> None:
        self.estimate: np.ndarray | None = None
        self.extent: np.ndarray | None = None
        self.points: np.ndarray | None = None
        self.fresh, self.flag, self.n_points = False, None, 0

    def new_episode(self, seed: int | None, model: mujoco.MjModel) -> None:
        """Forget the last estimate; the object's geoms and the platform's crop box from ``model`` (a family's
        object rebuilds it)."""
        self.rng = np.random.default_rng(None if seed is None else [seed, 44])
        self._object_geoms = np.flatnonzero(model.geom_bodyid == model.body(names.OBJECT_BODY).id)
        low, high = platform_crop(model)
        self.config = dataclasses.replace(self.config, crop_low=low, crop_high=high)
        self.placeholder = (np.asarray(low) + np.asarray(high)) / 2
        self.placeholder[2] = low[2]
        if self.estimator in MODEL_ESTIMATORS:
            support_rng = np.random.default_rng(None if seed is None else [seed, 45])
            self.support_error = float(support_rng.uniform(-self.support_error_m, self.support_error_m))
            if self._exact_model is None or self._exact_model[0] is not model:  # a family's draw is a new model
                self._exact_model = (model, ObjectModel.from_mujoco(model))
            exact = self._exact_model[1]
            self.object_model = dataclasses.replace(exact, support_z=None if exact.support_z is None
                                                    else exact.support_z + self.support_error)
        self._clear()

    def observe(self, camera: CameraClouds, hand_rotation: np.ndarray, hand_position: np.ndarray) -> ObjectEstimate:
        """This step's frame of ``camera`` (posed in hand_base) -> the object's estimate in the world."""
        frame = camera.frame
        world = dataclasses.replace(frame, camera_rotation=hand_rotation @ frame.camera_rotation,
                                    camera_position=hand_rotation @ frame.camera_position + hand_position)
        mask = self.mask_errors.apply(np.isin(camera.geoms, self._object_geoms), self.rng)
        cloud = object_cloud(world, mask, self.config, prior=self.estimate)
        result = estimate_object(world, mask, self.estimator, self.config, cloud=cloud, object_model=self.object_model)
        self.fresh, self.flag, self.n_points, self.points = result.estimate is not None, result.flag, \
            result.n_points, cloud.points
        if self.fresh:
            self.estimate, self.extent = result.estimate, result.extent
        return result

    @property
    def centre(self) -> np.ndarray:
        """The estimate, or the platform's middle before the first one."""
        return self.estimate if self.estimate is not None else self.placeholder

    @property
    def box(self) -> np.ndarray:
        """The visible extent, or zeros before the first estimate."""
        return self.extent if self.extent is not None else np.zeros(3)


__all__ = ["OBJECT_PERCEPTIONS", "TRUTH", "CameraObjectEstimate", "check_object_perception",
           "check_object_perception_with"]

"""Hand-eye refinement from the robot's own body: the camera's calibration error measured on a trial's first
frame and taken out of every frame after it.

Why: on the stand-in, the camera's object estimate is a few millimetres off at rest (``analysis/objects/``), but
the calibration error the camera path carries (up to 3 mm and 1 degree per axis, ``CameraClouds``) moves
everything it sees by up to about 2 cm at the object's distance; with that error set to zero the shipped
clone's first-attempt picks on the 2 cm sphere went from 2 to 9 of 12 (the truth arm: 11). A rig knows its own
geometry: the arm's and hand's links at the measured joint angles. So at the first frame the robot's points in
the depth image are aligned (ICP) onto the same links as the robot's model shows them from where the camera is
believed to be; the rigid motion that aligns them is the calibration error, inverted.

- the observed points: the depth frame's pixels of the robot's links (the simulator's segmentation stands in
  for the rig's, as for the object, with the same ``MaskErrors``), through the believed camera pose;
- the model points: the robot's model rendered from the believed camera pose (no noise), its links' pixels
  through that same pose: the links' visible surfaces where they truly are;
- a trimmed point-to-point ICP (``align``), its correspondence radius shrinking from ``start_radius_m`` to
  ``end_radius_m`` (the error moves points by up to about 2 cm; noise and the silhouettes' stray pixels are
  trimmed by the radius);
- the correction ``(R, t)`` maps believed camera poses onto corrected ones (``corrected_pose``); the residual
  (rms over the inliers) and the inlier count say how well it fit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
from scipy.spatial import cKDTree

from hingelab.camera import CameraFrame
from hingelab.perception.camera_cloud import depth_to_points, transform
from hingelab.perception.object_estimate import MaskErrors
from hingelab.sim import names

OBSERVED_POINTS = 4000  # observed robot points used per ICP (a random subset: enough for 6 DoF, fast)
MIN_POINTS = 200  # fewer robot points than this on either side: no refinement (flagged)


@dataclass(frozen=True)
class Alignment:
    """A rigid motion ``x -> rotation @ x + translation`` and how well it aligned: rms residual (m) over the
    ``inliers`` pairs within the final radius, of ``n_source`` points."""

    rotation: np.ndarray
    translation: np.ndarray
    rms_m: float
    inliers: int
    n_source: int

    @property
    def angle_deg(self) -> float:
        return float(np.degrees(np.arccos(np.clip((np.trace(self.rotation) - 1) / 2, -1.0, 1.0))))


def robot_geoms(model: mujoco.MjModel) -> np.ndarray:
    """The geoms of the robot's links (arm and hand): every body's but the world's, the tool's and the object's."""
    skip = {0, model.body(names.TOOL_BODY_A).id, model.body(names.TOOL_BODY_B).id, model.body(names.OBJECT_BODY).id}
    return np.flatnonzero(~np.isin(model.geom_bodyid, sorted(skip)))


def kabsch(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotation and translation that best map ``source`` onto ``target`` (paired rows), least squares."""
    source_mean, target_mean = source.mean(axis=0), target.mean(axis=0)
    u, _, vt = np.linalg.svd((source - source_mean).T @ (target - target_mean))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    rotation = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return rotation, target_mean - rotation @ source_mean


def align(source: np.ndarray, target: np.ndarray, iterations: int = 40, start_radius_m: float = 0.03,
          end_radius_m: float = 0.004) -> Alignment:
    """Trimmed point-to-point ICP of ``source`` onto ``target`` ((N, 3), (M, 3)), from the identity."""
    tree = cKDTree(target)
    rotation, translation = np.eye(3), np.zeros(3)
    radii = np.geomspace(start_radius_m, end_radius_m, iterations)
    inliers = np.zeros(len(source), bool)
    distance = np.full(len(source), np.inf)
    for radius in radii:
        moved = source @ rotation.T + translation
        distance, index = tree.query(moved, distance_upper_bound=radius)
        inliers = np.isfinite(distance)
        if inliers.sum() < MIN_POINTS // 2:
            break
        step_rotation, step_translation = kabsch(moved[inliers], target[index[inliers]])
        rotation, translation = step_rotation @ rotation, step_rotation @ translation + step_translation
    moved = source @ rotation.T + translation
    distance, _ = tree.query(moved, distance_upper_bound=end_radius_m)
    inliers = np.isfinite(distance)
    rms = float(np.sqrt(np.mean(distance[inliers] ** 2))) if inliers.any() else float("inf")
    return Alignment(rotation, translation, rms, int(inliers.sum()), len(source))


def refine_on_frame(renderer: Any, data: mujoco.MjData, frame: CameraFrame, geoms: np.ndarray,
                    rng: np.random.Generator, mask_errors: MaskErrors = MaskErrors()) -> Alignment | None:
    """The correction of ``frame``'s believed pose (hand_base) from the robot's points in it (``geoms``: the
    frame's geom id per pixel), or None when either side has fewer than ``MIN_POINTS`` robot points."""
    model = renderer.model
    links = robot_geoms(model)
    mask = mask_errors.apply(np.isin(geoms, links), rng)
    observed = transform(depth_to_points(frame.depth, frame.intrinsics, mask), frame.camera_rotation,
                         frame.camera_position)
    hand = model.body(names.HAND_BASE_BODY).id
    hand_rotation, hand_position = data.xmat[hand].reshape(3, 3), data.xpos[hand]
    depth, model_geoms = renderer.depth_and_geoms_at(data, hand_rotation @ frame.camera_rotation,
                                                     hand_rotation @ frame.camera_position + hand_position)
    expected = transform(depth_to_points(depth, frame.intrinsics, np.isin(model_geoms, links)), frame.camera_rotation,
                         frame.camera_position)
    if len(observed) < MIN_POINTS or len(expected) < MIN_POINTS:
        return None
    subset = observed[rng.choice(len(observed), min(OBSERVED_POINTS, len(observed)), replace=False)]
    return align(subset, expected)


def corrected_pose(alignment: Alignment, rotation: np.ndarray, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A believed camera pose (optical frame -> hand_base) with the alignment applied: points it places move by
    the alignment."""
    return alignment.rotation @ rotation, alignment.rotation @ position + alignment.translation


__all__ = ["Alignment", "align", "corrected_pose", "kabsch", "refine_on_frame", "robot_geoms"]

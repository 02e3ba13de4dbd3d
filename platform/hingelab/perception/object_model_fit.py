"""The object's known model fitted to its visible points: the ``mesh_fit`` estimator.

A single view sees the object's near side, and a real segmentation loses a pixel or two at the
boundary, most of all at the silhouette's far edge, where the visible depth is largest: every
estimator that reads the visible points alone lands toward the camera by an amount that depends on
the shape (``analysis/objects/object_estimate.md``: ray_corrected +4.4 mm on the 2 cm sphere, -0.8 on
the cube). Where the object is known (the trial's ``--object``, the env's object: the simulator's
model stands in for the rig's CAD model), its surface can be fitted to the points instead: each
visible point is matched to the nearest point of the model's camera-facing surface, so points that
the mask lost leave nothing to average toward the camera.

``ObjectModel.from_mujoco`` samples the surface of the object body's geoms (sphere, box, cylinder,
convex mesh) in the body's resting orientation. ``fit_model`` is a trimmed point-to-point ICP over
the model's position and its turn about the vertical (the object rests upright on the platform, its
yaw unknown): a few yaw starts run a few iterations each, the best goes on to convergence. The
estimate is the fitted model's centre, the middle of its resting height (what ToolPick-v0 observes
and ``true_object_centre`` gives).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import trimesh
from scipy.spatial import cKDTree

from hingelab.errors import ConfigError
from hingelab.perception.clouds import pose_matrix
from hingelab.sim import names
from hingelab.sim.geom_meshes import geom_in_body, geom_mesh

MODEL_SAMPLES = 1000  # surface points of the model (about 1.5 mm apart on a 2 cm cube)
YAW_STARTS = 8  # yaw starts, evenly over a turn (a tetrahedron repeats every 120 degrees, a cube every 90)
START_ITERATIONS = 4  # iterations of every start before the best is kept
ITERATIONS = 25  # iterations of the kept start at most
KEEP = 0.8  # the share of the matches kept (the nearest): drops a wrong blob's points and stray pixels
CONVERGED_M = 1e-5  # a step that moves the model less than this ends the iterations
RESTING_M = 0.005  # a free fit whose lowest point is this near the support rests on it: fitted again at its height


@dataclass(frozen=True)
class ObjectModel:
    """The object's surface: ``points`` and outward ``normals`` (K, 3), m, in the body's resting orientation
    (the world's axes at yaw 0, origin at the body's origin), ``centre`` (3,), the middle of its
    resting height in that frame, ``bottom`` its lowest height in that frame, and ``support_z``, the height
    of the surface it rests on in the world (the platform's top; None: not known)."""

    points: np.ndarray
    normals: np.ndarray
    centre: np.ndarray
    bottom: float
    support_z: float | None = None

    @classmethod
    def from_mujoco(cls, model: mujoco.MjModel, body: str = names.OBJECT_BODY, samples: int = MODEL_SAMPLES,
                    seed: int = 0) -> ObjectModel:
        """Sample the surface of ``body``'s geoms in ``model`` (as compiled: a mesh is its convex hull); the
        support is the top of the model's ``platform`` geom where it has one."""
        body_id = model.body(body).id
        meshes = [_geom_mesh(model, g) for g in np.flatnonzero(model.geom_bodyid == body_id)]
        if not meshes:
            raise ConfigError(f"the model has no geoms on body {body!r} to fit")
        surface = trimesh.util.concatenate(meshes)
        resting = pose_matrix(np.zeros(3), model.body_quat[body_id])[0]
        surface.apply_transform(np.block([[resting, np.zeros((3, 1))], [np.zeros((1, 3)), np.ones((1, 1))]]))
        points, faces = trimesh.sample.sample_surface_even(surface, samples, seed=seed)
        if len(points) < samples // 2:  # sample_surface_even rejects points closer than its spacing
            points, faces = trimesh.sample.sample_surface(surface, samples, seed=seed)
        low, high = surface.bounds
        centre = np.array([0.0, 0.0, (low[2] + high[2]) / 2])  # on the body's vertical axis
        platform = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "platform")
        support = None if platform < 0 else float(model.geom_pos[platform][2] + model.geom_size[platform][2])
        return cls(np.asarray(points, float), np.asarray(surface.face_normals[faces], float), centre,
                   float(low[2]), support)


def _geom_mesh(model: mujoco.MjModel, g: int) -> trimesh.Trimesh:
    """Geom ``g``'s surface in its body's frame (a mesh geom as its vertices' convex hull, what MuJoCo collides)."""
    mesh = geom_mesh(model, g, sections=48, sphere_subdivisions=3)
    if mesh is None:
        raise ConfigError(f"cannot fit an object geom of type {mujoco.mjtGeom(model.geom_type[g]).name}")
    if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
        mesh = trimesh.convex.convex_hull(mesh.vertices)
    mesh.apply_transform(geom_in_body(model, g))
    return mesh


@dataclass(frozen=True)
class ModelFit:
    """The fitted pose (``translation`` (3,) m and ``yaw`` rad, applied to the model's frame), its ``centre``
    (3,) (the estimate), the trimmed matches' rms distance (m) and how many points were matched."""

    centre: np.ndarray
    translation: np.ndarray
    yaw: float
    rms_m: float
    matched: int


def _yaw_matrix(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _iterate(points: np.ndarray, camera: np.ndarray, model: ObjectModel, translation: np.ndarray, yaw: float,
             iterations: int, height: float | None = None) -> tuple[np.ndarray, float, float, int]:
    """Up to ``iterations`` ICP steps from (translation, yaw): (translation, yaw, rms of the kept matches, kept).
    ``height``: the translation's height held there (the object resting on its support)."""
    rms, kept = np.inf, 0
    for _ in range(iterations):
        rotation = _yaw_matrix(yaw)
        world = model.points @ rotation.T + translation
        facing = np.einsum("ij,ij->i", model.normals @ rotation.T, camera - world) > 0
        if np.count_nonzero(facing) < 3:
            break
        distance, index = cKDTree(world[facing]).query(points)
        keep = distance <= np.quantile(distance, KEEP)
        matched, observed = model.points[facing][index[keep]], points[keep]
        rms, kept = float(np.sqrt(np.mean(distance[keep] ** 2))), int(np.count_nonzero(keep))
        # the best yaw and translation for these matches: vertical shift by the means, yaw by 2-D Procrustes
        m_mean, p_mean = matched.mean(axis=0), observed.mean(axis=0)
        mc, pc = matched[:, :2] - m_mean[:2], observed[:, :2] - p_mean[:2]
        new_yaw = float(np.arctan2(np.sum(mc[:, 0] * pc[:, 1] - mc[:, 1] * pc[:, 0]), np.sum(mc * pc)))
        new_translation = p_mean - _yaw_matrix(new_yaw) @ m_mean
        if height is not None:
            new_translation[2] = height
        step = np.linalg.norm(new_translation - translation) + 0.01 * abs(np.angle(np.exp(1j * (new_yaw - yaw))))
        translation, yaw = new_translation, new_yaw
        if step < CONVERGED_M:
            break
    return translation, yaw, rms, kept


def fit_model(points: np.ndarray, camera_position: np.ndarray, model: ObjectModel, start: np.ndarray) -> ModelFit:
    """The trimmed ICP of the module doc: ``points`` (N, 3) the visible points and ``camera_position`` (3,) in
    the world; ``start`` (3,) where the model's centre starts (another estimator's estimate). A free fit
    (position and yaw) whose lowest point lands within ``RESTING_M`` of the model's support is fitted again
    with its height held at resting on it: a view of one or two faces of a polyhedron leaves the model free to
    slide along their common edge, and the support stops that; a lifted object keeps the free fit."""
    points = np.asarray(points, float)
    camera = np.asarray(camera_position, float)
    fits = []
    for yaw in np.arange(YAW_STARTS) * 2 * np.pi / YAW_STARTS:
        translation = np.asarray(start, float) - _yaw_matrix(yaw) @ model.centre
        fits.append(_iterate(points, camera, model, translation, float(yaw), START_ITERATIONS))
    translation, yaw, _, _ = min(fits, key=lambda fit: fit[2])
    translation, yaw, rms, kept = _iterate(points, camera, model, translation, yaw, ITERATIONS)
    if model.support_z is not None and abs(translation[2] + model.bottom - model.support_z) <= RESTING_M:
        resting = model.support_z - model.bottom
        translation, yaw, rms, kept = _iterate(points, camera, model, np.array([*translation[:2], resting]), yaw,
                                               ITERATIONS, height=resting)
    return ModelFit(translation + _yaw_matrix(yaw) @ model.centre, translation, yaw, rms, kept)


__all__ = ["ModelFit", "ObjectModel", "fit_model"]

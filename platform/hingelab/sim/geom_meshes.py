"""A compiled MuJoCo geom as a triangle mesh in its body's frame (trimesh): what the viewers draw and what the
object's model fit (``hingelab.perception.object_model_fit``) samples."""

from __future__ import annotations

import mujoco
import numpy as np
import trimesh


def geom_mesh(model: mujoco.MjModel, g: int, sections: int = 16,
              sphere_subdivisions: int = 2) -> trimesh.Trimesh | None:
    """Geom ``g``'s surface in its own frame: boxes, cylinders, capsules, spheres and ellipsoids tessellated
    (``sections`` around a cylinder or capsule, ``sphere_subdivisions`` of an icosphere), a mesh geom as its
    compiled vertices and faces; None for planes, heightfields and SDFs."""
    kind, size = model.geom_type[g], model.geom_size[g]
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return trimesh.creation.box(extents=2 * size)
    if kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return trimesh.creation.cylinder(radius=size[0], height=2 * size[1], sections=sections)
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return trimesh.creation.capsule(height=2 * size[1], radius=size[0], count=[sections, sections])
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return trimesh.creation.icosphere(subdivisions=sphere_subdivisions, radius=size[0])
    if kind == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
        sphere = trimesh.creation.icosphere(subdivisions=sphere_subdivisions, radius=1.0)
        sphere.apply_scale(size)
        return sphere
    if kind == mujoco.mjtGeom.mjGEOM_MESH:
        m = model.geom_dataid[g]
        v0, nv = model.mesh_vertadr[m], model.mesh_vertnum[m]
        f0, nf = model.mesh_faceadr[m], model.mesh_facenum[m]
        return trimesh.Trimesh(model.mesh_vert[v0:v0 + nv].copy(), model.mesh_face[f0:f0 + nf].copy(), process=False)
    return None


def geom_in_body(model: mujoco.MjModel, g: int) -> np.ndarray:
    """(4, 4) geom ``g``'s pose in its body's frame."""
    pose = np.eye(4)
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, model.geom_quat[g])
    pose[:3, :3] = rot.reshape(3, 3)
    pose[:3, 3] = model.geom_pos[g]
    return pose


__all__ = ["geom_in_body", "geom_mesh"]

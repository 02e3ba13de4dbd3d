"""The graspable objects: shapes, sizes and masses, and building their geoms in an MjSpec.

``size`` is the object's characteristic width in metres, the opening the tweezer must
span: a sphere's or cylinder's diameter (the cylinder is as tall as it is wide), a
cube's or regular tetrahedron's edge; a mesh's largest extent. The paper trains on a
1 cm radius, 10 g sphere and tests a sphere, cube, cylinder and tetrahedron of 1.5 to 2.5 cm.

``shape`` may also be ``mesh:PATH``: an STL, OBJ or PLY file, collided through its convex
hull and scaled so its largest extent is ``size`` (``hingelab.sim.mesh_objects``).

``family:NAME[:SEED]`` is not one object but a procedural family of them, drawn anew every episode
(``hingelab.sim.object_families``): ToolPick-v0 takes it, and each draw is a ``DrawnObject``, an
``ObjectSpec`` made of convex pieces.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from hingelab.errors import ConfigError
from hingelab.sim.mesh_objects import MESH_PREFIX, is_mesh, load_unit_hull, mesh_path

SHAPES = ("sphere", "cube", "cylinder", "tetrahedron")
FAMILY_PREFIX = "family:"  # family:NAME[:SEED], a procedural family (hingelab.sim.object_families)
TRAINING_OBJECT = ("sphere", 0.02, 0.010)  # shape, size (m), mass (kg): the paper's training sphere
TEST_SIZE_RANGE = (0.015, 0.025)  # the paper's test objects, metres
# the pick table's 12 shape-size sets: the paper's test objects (Fig. 7), at the training object's mass
PICK_SETS = tuple((shape, size) for shape in ("sphere", "cube", "cylinder", "tetrahedron")
                  for size in (0.015, 0.02, 0.025))
# What the scene accepts: the tweezer's tips open 0 to ~38 mm (hinge 0 to 0.3 rad).
SIZE_LIMITS = (0.005, 0.035)
MASS_LIMITS = (0.001, 0.2)
# A mesh object, scaled: at least SIZE_LIMITS[0] wide along y (what the tips close on) and
# this thick along x and z (thinner is a sheet lying on the platform, below the tips' pads).
MESH_MIN_THICKNESS = 0.001


@dataclass(frozen=True)
class ObjectSpec:
    """One graspable object. size: metres (see module doc); mass: kg; friction: sliding."""

    shape: str = "sphere"
    size: float = 0.02
    mass: float = 0.010
    friction: float = 1.0

    def __post_init__(self):
        if isinstance(self.shape, str) and self.shape.startswith(FAMILY_PREFIX):
            raise ConfigError(f"{self.shape} is a family of objects, drawn per episode: give it to ToolPick-v0 "
                              f"(--object), or draw one with hingelab.sim.object_families.ObjectFamily")
        if not (self.shape in SHAPES or is_mesh(self.shape)):
            raise ConfigError(
                f"unknown object {self.shape!r}; choose one of: {', '.join(SHAPES)}, {MESH_PREFIX}PATH "
                f"(an STL, OBJ or PLY file), or {FAMILY_PREFIX}NAME[:SEED] (a procedural family)"
            )
        if not np.isfinite(self.size) or not SIZE_LIMITS[0] <= self.size <= SIZE_LIMITS[1]:
            what = f"mesh {mesh_path(self.shape)} scaled to largest extent" if self.is_mesh else "object size"
            raise ConfigError(
                f"{what} {self.size!r} m is out of range: the tweezer grasps "
                f"{SIZE_LIMITS[0]} to {SIZE_LIMITS[1]} m (give --size in metres, e.g. 0.02 for 2 cm)"
            )
        if self.is_mesh:
            x, y, z = load_unit_hull(self.shape).extent * self.size
            if y < SIZE_LIMITS[0]:
                raise ConfigError(
                    f"mesh {mesh_path(self.shape)} scaled to {self.size:g} m is only {1000 * y:.1f} mm wide "
                    f"along y (the tips' closing direction); the tweezer grasps {1000 * SIZE_LIMITS[0]:g} to "
                    f"{1000 * SIZE_LIMITS[1]:g} mm: give a larger --size or rotate the mesh in its file"
                )
            if min(x, z) < MESH_MIN_THICKNESS:
                raise ConfigError(
                    f"mesh {mesh_path(self.shape)} scaled to {self.size:g} m is only {1000 * min(x, z):.2f} mm "
                    f"thick along {'x' if x < z else 'z'}, a sheet, not an object the tweezer can pick (at least "
                    f"{1000 * MESH_MIN_THICKNESS:g} mm): give a larger --size or a solid mesh"
                )
        if not np.isfinite(self.mass) or not MASS_LIMITS[0] <= self.mass <= MASS_LIMITS[1]:
            raise ConfigError(
                f"object mass {self.mass!r} kg is out of range {MASS_LIMITS[0]} to {MASS_LIMITS[1]} kg"
            )

    @property
    def is_mesh(self) -> bool:
        return is_mesh(self.shape)

    @property
    def height(self) -> float:
        """Height when resting (a tetrahedron stands on a face, a mesh as in its file), metres."""
        if self.is_mesh:
            return float(self._unit_hull().extent[2]) * self.size
        return self.size * np.sqrt(2.0 / 3.0) if self.shape == "tetrahedron" else self.size

    def width_at(self, height: float) -> float:
        """Extent along the world y axis (the tips' closing direction) at ``height`` above the
        resting surface, for the object placed unrotated, metres."""
        z = float(np.clip(height, 0.0, self.height))
        if self.is_mesh:  # the hull's slice at that height (exact for the hull)
            return self._unit_hull().width_at(z / self.size) * self.size
        if self.shape == "sphere":
            r = self.size / 2
            return 2 * float(np.sqrt(max(r * r - (z - r) ** 2, 0.0)))
        if self.shape == "tetrahedron":
            return self.size * (1.0 - z / self.height)  # an edge lies along y at the base
        return self.size

    @property
    def rest_height(self) -> float:
        """Height of the body origin above the surface it rests on, metres."""
        if self.shape == "tetrahedron":
            return 0.0  # mesh origin is on its base face
        if self.is_mesh:
            return self.height / 2  # origin at the hull's bounding-box centre
        return self.size / 2

    @property
    def centre_height(self) -> float:
        """Height of the resting object's bounding-box centre above its body origin, metres (0 but for
        the tetrahedron, whose origin is on its base face)."""
        return self.height / 2 - self.rest_height

    def mesh_vertices(self) -> np.ndarray:
        """A mesh object's hull vertices in the body frame, metres (n, 3)."""
        return self._unit_hull().vertices * self.size

    def mesh_pieces(self) -> list[tuple[np.ndarray, float]]:
        """A mesh object's collision meshes: (vertices in the body frame (n, 3) m, mass kg) each; one here,
        several convex pieces for a ring drawn from a family."""
        return [(self.mesh_vertices(), self.mass)]

    def _unit_hull(self):
        return load_unit_hull(self.shape)


def tetrahedron_vertices(edge: float) -> np.ndarray:
    """Regular tetrahedron standing on a face; origin at the base face's centroid. (4, 3)."""
    r = edge / np.sqrt(3.0)  # circumradius of the base triangle
    h = edge * np.sqrt(2.0 / 3.0)
    base = [(r * np.cos(a), r * np.sin(a), 0.0) for a in (0.0, 2 * np.pi / 3, 4 * np.pi / 3)]
    return np.array(base + [(0.0, 0.0, h)])


def add_object_geom(spec: mujoco.MjSpec, body: mujoco.MjsBody, obj: ObjectSpec) -> None:
    """Add ``obj``'s collision geom (named ``object_geom``) to ``body``, with its mass; a mesh of several
    convex pieces adds ``object_geom_1``, ... too, each with its share of the mass."""
    kwargs = dict(name="object_geom", mass=obj.mass, friction=[obj.friction, 0.01, 0.0001],
                  condim=4, rgba=[0.1, 0.2, 0.6, 1.0])
    if obj.shape == "sphere":
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[obj.size / 2, 0, 0], **kwargs)
    elif obj.shape == "cube":
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[obj.size / 2] * 3, **kwargs)
    elif obj.shape == "cylinder":
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[obj.size / 2, obj.size / 2, 0], **kwargs)
    else:
        mesh_name = "object_mesh" if obj.is_mesh else "object_tetrahedron"
        pieces = obj.mesh_pieces() if obj.is_mesh else [(tetrahedron_vertices(obj.size), obj.mass)]
        for index, (vertices, mass) in enumerate(pieces):
            suffix = f"_{index}" if index else ""
            existing = spec.mesh(mesh_name + suffix)
            if existing is not None:
                spec.delete(existing)
            spec.add_mesh(name=mesh_name + suffix, uservert=vertices.ravel().tolist())
            body.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mesh_name + suffix,
                          **{**kwargs, "name": kwargs["name"] + suffix, "mass": mass})

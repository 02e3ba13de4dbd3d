"""The ``/scene`` topic (schema 6): an episode's object, target, tips and platform as ``foxglove.SceneUpdate``.

Foxglove's 3-D panel does not draw ``Point3InFrame`` (``/object/position``, ``/target/position``), so every step
that has any of them also logs one SceneUpdate in ``hand_base`` with one entity per thing it knows, under the
stable ids ``schemas.SCENE_ENTITIES``. Sizes are metres, as the primitives' ``size`` (full extents, not radii):

- ``object``: the recorded shape (``sphere``, ``cube``, ``cylinder``; a tetrahedron as a cone; any other, a
  mesh or a family's draw, as a sphere) of the recorded width (``ObjectSpec.size``: a sphere's diameter, a
  cube's edge), posed by the simulator's object orientation where it is recorded;
- ``target``: a translucent sphere 2 cm across (ToolPick-v0's success: the object within 1 cm of it);
- ``tip_a``, ``tip_b``: spheres ``TIP_DIAMETER_M`` across at the tweezer's tips (simulator episodes);
- ``platform``: a box of the platform's size and pose, where the recording knows it.
"""

from __future__ import annotations

import math

import numpy as np
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.CylinderPrimitive_pb2 import CylinderPrimitive
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.SpherePrimitive_pb2 import SpherePrimitive
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3

from hingelab.episodes import schemas as S

TIP_DIAMETER_M = 0.004  # the tips' markers: 4 mm spheres
TARGET_DIAMETER_M = 0.02  # ToolPick-v0's success radius is 1 cm
DEFAULT_OBJECT_SIZE_M = 0.02  # the training sphere, when an episode records no size
COLORS = {  # r, g, b, a
    S.SCENE_OBJECT: (0.95, 0.55, 0.1, 1.0),
    S.SCENE_TARGET: (0.1, 0.8, 0.3, 0.35),
    S.SCENE_TIP_A: (0.9, 0.1, 0.1, 1.0),
    S.SCENE_TIP_B: (0.1, 0.3, 0.9, 1.0),
    S.SCENE_PLATFORM: (0.6, 0.6, 0.6, 0.5),
}


def object_primitive_kind(shape: str) -> str:
    """The primitive that draws an object of ``shape``: ``"sphere"``, ``"cube"``, ``"cylinder"`` or ``"cone"``."""
    return {"cube": "cube", "cylinder": "cylinder", "tetrahedron": "cone"}.get(shape, "sphere")


def _set_pose(pose: Pose, position, orientation_xyzw=None) -> None:
    p = pose.position
    p.x, p.y, p.z = _floats(position, 3)
    q = pose.orientation
    q.x, q.y, q.z, q.w = (0.0, 0.0, 0.0, 1.0) if orientation_xyzw is None else _floats(orientation_xyzw, 4)


def _floats(values, n: int) -> list[float]:
    """``values`` as n Python floats (plain Python: numpy's per-call overhead dominates on 3 numbers)."""
    out = [float(v) for v in (values.reshape(-1) if isinstance(values, np.ndarray) else values)]
    if len(out) != n:
        raise ValueError(f"expected {n} numbers, got {len(out)}")
    return out


def _entity(entity_id: str, kind: str, size) -> SceneEntity:
    """An entity of one primitive at the origin (its pose and timestamp are set per message)."""
    sx, sy, sz = (float(v) for v in size)
    color = Color(**dict(zip("rgba", COLORS[entity_id])))
    entity = SceneEntity(frame_id=S.FRAME_HAND, id=entity_id, frame_locked=False)
    dims = Vector3(x=sx, y=sy, z=sz)
    pose = Pose(position=Vector3(), orientation=Quaternion(w=1.0))
    if kind == "cube":
        entity.cubes.append(CubePrimitive(pose=pose, size=dims, color=color))
    elif kind in ("cylinder", "cone"):
        entity.cylinders.append(CylinderPrimitive(pose=pose, size=dims, bottom_scale=1.0,
                                                  top_scale=0.0 if kind == "cone" else 1.0, color=color))
    else:
        entity.spheres.append(SpherePrimitive(pose=pose, size=dims, color=color))
    return entity


class SceneEncoder:
    """Serializes an episode's ``/scene`` messages. One per writer: it keeps the SceneUpdate of the last set of
    entities and only moves their poses and timestamps (building the message anew costs ~10x more)."""

    def __init__(self):
        self._key = None
        self._update: SceneUpdate | None = None

    def encode(self, log_time_ns: int, *, object_position=None, object_orientation=None, object_shape: str = "sphere",
               object_size=DEFAULT_OBJECT_SIZE_M, target_position=None, tip_a=None, tip_b=None,
               platform=None) -> bytes | None:
        """One ``foxglove.SceneUpdate`` (serialized) with an entity for each thing given, or None if none is.

        Positions (3,) m and orientations (4,) x, y, z, w in hand_base. ``object_size``: the width (m) or the
        extents (3,) m. ``platform``: (centre (3,) m, orientation (4,) xyzw, size (3,) m) in hand_base.
        """
        parts = []  # (entity id, primitive kind, size (3,), position, orientation)
        if _finite(object_position):
            size = tuple(_floats(object_size, 3)) if np.ndim(object_size) else (float(object_size),) * 3
            parts.append((S.SCENE_OBJECT, object_primitive_kind(object_shape), size, object_position,
                          object_orientation))
        if _finite(target_position):
            parts.append((S.SCENE_TARGET, "sphere", (TARGET_DIAMETER_M,) * 3, target_position, None))
        for entity_id, tip in ((S.SCENE_TIP_A, tip_a), (S.SCENE_TIP_B, tip_b)):
            if _finite(tip):
                parts.append((entity_id, "sphere", (TIP_DIAMETER_M,) * 3, tip, None))
        if platform is not None:
            centre, orientation, size = platform
            parts.append((S.SCENE_PLATFORM, "cube", tuple(_floats(size, 3)), centre, orientation))
        if not parts:
            return None
        key = tuple((entity_id, kind, size) for entity_id, kind, size, _, _ in parts)
        if key != self._key:
            self._key = key
            self._update = SceneUpdate(entities=[_entity(entity_id, kind, size) for entity_id, kind, size in key])
        for entity, (_, _, _, position, orientation) in zip(self._update.entities, parts):
            entity.timestamp.seconds, entity.timestamp.nanos = divmod(int(log_time_ns), 1_000_000_000)
            primitive = (entity.cubes or entity.cylinders or entity.spheres)[0]
            _set_pose(primitive.pose, position, orientation)
        return self._update.SerializeToString()


def encode_scene_update(log_time_ns: int, **things) -> bytes | None:
    """``SceneEncoder().encode``: one message on its own (see there for the arguments)."""
    return SceneEncoder().encode(log_time_ns, **things)


def _finite(position) -> bool:
    return position is not None and all(math.isfinite(v) for v in _floats(position, 3))


__all__ = ["SceneEncoder", "encode_scene_update", "object_primitive_kind", "TIP_DIAMETER_M", "TARGET_DIAMETER_M",
           "DEFAULT_OBJECT_SIZE_M"]

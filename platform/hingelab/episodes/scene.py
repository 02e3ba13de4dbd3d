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

from hingelab.episodes import codec
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


def _pose(position, orientation_xyzw=None) -> Pose:
    x, y, z = (float(v) for v in np.asarray(position, float).reshape(3))
    qx, qy, qz, qw = (0.0, 0.0, 0.0, 1.0) if orientation_xyzw is None else \
        (float(v) for v in np.asarray(orientation_xyzw, float).reshape(4))
    return Pose(position=Vector3(x=x, y=y, z=z), orientation=Quaternion(x=qx, y=qy, z=qz, w=qw))


def _entity(stamp, entity_id: str, kind: str, pose: Pose, size) -> SceneEntity:
    sx, sy, sz = (float(v) for v in size)
    color = Color(**dict(zip("rgba", COLORS[entity_id])))
    entity = SceneEntity(timestamp=stamp, frame_id=S.FRAME_HAND, id=entity_id, frame_locked=False)
    dims = Vector3(x=sx, y=sy, z=sz)
    if kind == "cube":
        entity.cubes.append(CubePrimitive(pose=pose, size=dims, color=color))
    elif kind in ("cylinder", "cone"):
        entity.cylinders.append(CylinderPrimitive(pose=pose, size=dims, bottom_scale=1.0,
                                                  top_scale=0.0 if kind == "cone" else 1.0, color=color))
    else:
        entity.spheres.append(SpherePrimitive(pose=pose, size=dims, color=color))
    return entity


def encode_scene_update(log_time_ns: int, *, object_position=None, object_orientation=None,
                        object_shape: str = "sphere", object_size=DEFAULT_OBJECT_SIZE_M, target_position=None,
                        tip_a=None, tip_b=None, platform=None) -> bytes | None:
    """One ``foxglove.SceneUpdate`` (serialized) with an entity for each thing given, or None if none is.

    Positions (3,) m and orientations (4,) x, y, z, w in hand_base. ``object_size``: the width (m) or the
    extents (3,) m. ``platform``: (centre (3,) m, orientation (4,) xyzw, size (3,) m) in hand_base.
    """
    stamp = codec.timestamp(log_time_ns)
    entities = []
    if object_position is not None and np.all(np.isfinite(object_position)):
        size = np.broadcast_to(np.asarray(object_size, float), (3,))
        entities.append(_entity(stamp, S.SCENE_OBJECT, object_primitive_kind(object_shape),
                                _pose(object_position, object_orientation), size))
    if target_position is not None and np.all(np.isfinite(target_position)):
        entities.append(_entity(stamp, S.SCENE_TARGET, "sphere", _pose(target_position), [TARGET_DIAMETER_M] * 3))
    for entity_id, tip in ((S.SCENE_TIP_A, tip_a), (S.SCENE_TIP_B, tip_b)):
        if tip is not None and np.all(np.isfinite(tip)):
            entities.append(_entity(stamp, entity_id, "sphere", _pose(tip), [TIP_DIAMETER_M] * 3))
    if platform is not None:
        centre, orientation, size = platform
        entities.append(_entity(stamp, S.SCENE_PLATFORM, "cube", _pose(centre, orientation), size))
    if not entities:
        return None
    return SceneUpdate(entities=entities).SerializeToString()


__all__ = ["encode_scene_update", "object_primitive_kind", "TIP_DIAMETER_M", "TARGET_DIAMETER_M",
           "DEFAULT_OBJECT_SIZE_M"]

"""Loading a scene: the file, its object swapped at run time, clear errors on bad assets."""

from __future__ import annotations

from pathlib import Path

import mujoco

from hingelab.errors import AssetError, ConfigError
from hingelab.paths import SCENES_DIR
from hingelab.sim import names
from hingelab.sim.objects import ObjectSpec, add_object_geom
from hingelab.sim.rig_camera import add_rig_camera

REBUILD_HINT = "restore it from git or rebuild the scenes with `python -m hingelab.sim.scene_builder`"


def scene_path(scene: str) -> Path:
    """assets/scenes/SCENE.xml for a scene name, or an explicit .xml path."""
    if scene.endswith(".xml"):
        return Path(scene)
    if scene not in names.SCENES:
        raise ConfigError(f"unknown scene {scene!r}; choose one of: {', '.join(names.SCENES)}")
    return SCENES_DIR / f"{scene}.xml"


def load_spec(scene: str) -> mujoco.MjSpec:
    path = scene_path(scene)
    if not path.is_file():
        raise AssetError(f"scene file {path} is missing; {REBUILD_HINT}")
    try:
        return mujoco.MjSpec.from_file(str(path))
    except ValueError as exc:  # MuJoCo's XML parser and compiler raise ValueError
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else "unreadable"
        raise AssetError(f"scene file {path} is malformed ({first}); {REBUILD_HINT}") from exc


def load_scene(scene: str = "tool_pick", obj: ObjectSpec | None = None, camera=None) -> mujoco.MjModel:
    """Compile a scene, with the pick scene's object replaced by ``obj`` if given.

    ``camera``: a ``rig_camera.DepthIntrinsics`` to add the rig's depth camera with (None: no
    camera; a camera changes nothing in the physics).

    The swapped object keeps the body name ``object`` and its free joint; its geom gets the
    requested shape, size and mass. Its resting height is corrected at reset (``SimCore``).
    """
    spec = load_spec(scene)
    if obj is not None:
        body = spec.body(names.OBJECT_BODY)
        if body is None:
            raise ConfigError(f"scene {scene!r} has no object to swap; objects belong to tool_pick")
        for geom in list(body.geoms):
            spec.delete(geom)
        add_object_geom(spec, body, obj)
    if camera is not None:
        add_rig_camera(spec, scene_path(scene).stem, camera)
    try:
        model = spec.compile()
    except ValueError as exc:
        first = str(exc).strip().splitlines()[0]
        raise AssetError(f"scene {scene_path(scene)} does not compile ({first}); {REBUILD_HINT}") from exc
    _check_interface(model, scene)
    return model


def _check_interface(model: mujoco.MjModel, scene: str) -> None:
    """The public names every consumer relies on must be present."""
    required = [("body", names.HAND_BASE_BODY), ("body", names.TOOL_BODY_A), ("body", names.TOOL_BODY_B),
                ("joint", names.TOOL_HINGE), ("site", names.TOOL_TIP_SITES[0]), ("site", names.TOOL_TIP_SITES[1])]
    required += [("actuator", a) for a in names.HAND_ACTUATORS]
    for kind, name in required:
        if mujoco.mj_name2id(model, getattr(mujoco.mjtObj, f"mjOBJ_{kind.upper()}"), name) < 0:
            raise AssetError(f"scene {scene_path(scene)} lacks {kind} {name!r}; {REBUILD_HINT}")
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, names.GRASP_KEYFRAME) < 0:
        raise AssetError(f"scene {scene_path(scene)} lacks the {names.GRASP_KEYFRAME!r} keyframe; {REBUILD_HINT}")

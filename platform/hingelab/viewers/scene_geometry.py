"""The pick scene's geometry and its body poses per step, for the viewers (numpy + MuJoCo, no Rerun).

``scene_meshes(model)``: one triangle mesh per body of the compiled MuJoCo model, every geom of the
body merged into it (boxes, cylinders, capsules, spheres, ellipsoids as tessellated primitives; mesh
geoms as their compiled vertices), vertices in the **body's frame** (metres) with the geoms' colours.
The world body's geoms (the platform) form the mesh ``world``; the table is left out (1.2 m wide, it
would frame the view on itself).

``scene_poses(model, episode)``: every body's pose per step **in hand_base** (``schemas.FRAME_HAND``,
the frame of everything an episode records and the root of the viewers' 3-D view), from

- the hand's bodies: the recorded 9 hand joints (``/hand/joints``, couplings applied) through
  ``mj_kinematics`` (a pose relative to hand_base needs only the hand's joints);
- the tweezer: the recorded body pose where the episode has it (``/sim/privileged`` tool position and
  orientation = body ``tool_leg_a``), else the registered tool pose (``/tool/pose``); leg b from the
  recorded hinge angle, else the opening read off the recorded latent (``opening_of_z``: the encoder's
  calibration), else the ``grasp`` keyframe's;
- the object: ``/sim/privileged`` object position and orientation, else ``/object/position`` with no
  rotation;
- the arm and the platform: the recorded arm joints (``/arm/joints``, or real imports' step infos
  ``arm_joint_1..6``) through ``mj_kinematics``. Episodes without arm joints (simulated rollouts) do
  not say where the hand is in the world: their arm and platform are left out (``has_arm`` False).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from hingelab.episodes import Episode
from hingelab.episodes import schemas as S
from hingelab.errors import ConfigError
from hingelab.sim import names
from hingelab.sim.geom_meshes import geom_in_body, geom_mesh
from hingelab.sim.hand import HandCoupling

PRIMITIVE_SECTIONS = 16  # segments around a cylinder or capsule: smooth enough at a hand's scale
WORLD_MESH = "world"
LEFT_OUT_GEOMS = ("table",)
TOOL_ALPHA = 110  # the tweezer's meshes half transparent: the tool cloud on its surface stays visible


@dataclass
class BodyMesh:
    """One body's geometry: ``vertices`` (V, 3) float32 metres in the body frame, ``triangles`` (F, 3)
    uint32, ``colors`` (V, 4) uint8 RGBA; ``part`` is arm, hand, tool, object or scene."""

    name: str
    body_id: int
    part: str
    vertices: np.ndarray
    triangles: np.ndarray
    colors: np.ndarray


def _part(body_name: str) -> str:
    if body_name.startswith("arm_"):
        return "arm"
    if body_name.startswith("svh_") or body_name == names.HAND_BASE_BODY:
        return "hand"
    if body_name.startswith("tool_"):
        return "tool"
    if body_name == names.OBJECT_BODY:
        return "object"
    return "scene"


def scene_meshes(model: mujoco.MjModel) -> list[BodyMesh]:
    """One ``BodyMesh`` per body with visible geoms (see the module docstring), in body id order."""
    per_body: dict[int, list[tuple[trimesh.Trimesh, np.ndarray]]] = {}
    for g in range(model.ngeom):
        if model.geom_rgba[g][3] <= 0 or model.geom(g).name in LEFT_OUT_GEOMS:
            continue
        mesh = geom_mesh(model, g, sections=PRIMITIVE_SECTIONS)
        if mesh is None:
            continue
        mesh.apply_transform(geom_in_body(model, g))
        per_body.setdefault(int(model.geom_bodyid[g]), []).append((mesh, model.geom_rgba[g]))
    out = []
    for body, parts in sorted(per_body.items()):
        vertices, triangles, colors, offset = [], [], [], 0
        for mesh, rgba in parts:
            vertices.append(np.asarray(mesh.vertices, np.float32))
            triangles.append(np.asarray(mesh.faces, np.uint32) + offset)
            colors.append(np.tile(np.round(np.asarray(rgba) * 255).astype(np.uint8), (len(mesh.vertices), 1)))
            offset += len(mesh.vertices)
        name = WORLD_MESH if body == 0 else model.body(body).name
        colors = np.concatenate(colors)
        if _part(name) == "tool":
            colors[:, 3] = TOOL_ALPHA
        out.append(BodyMesh(name, body, _part(name), np.concatenate(vertices), np.concatenate(triangles), colors))
    return out


@dataclass
class ScenePoses:
    """Body poses per step in hand_base: ``translation`` (T, B, 3) metres, ``quaternion`` (T, B, 4) x y z w,
    for the bodies ``body_ids`` (B,); ``step`` (T,) the steps' indices and ``step_time_ns`` (T,) their log
    times; ``has_arm``: the arm joints were recorded; ``sources``: part -> where its poses came from (for the
    facts panel and the tests)."""

    body_ids: np.ndarray
    translation: np.ndarray
    quaternion: np.ndarray
    step: np.ndarray
    step_time_ns: np.ndarray
    has_arm: bool
    sources: dict[str, str]


def _qpos_adr(model: mujoco.MjModel, joint: str) -> int:
    return int(model.jnt_qposadr[model.joint(joint).id])


def _hand_qpos_adr(model: mujoco.MjModel, joint: str) -> int:
    """A recorded hand joint's qpos address: episodes name the 9 SVH channels ``schemas.SVH_JOINT_NAMES``
    (the model's ``names.HAND_ACTUATORS``, same order) or by the model's own joint names."""
    if joint in S.SVH_JOINT_NAMES:
        joint = names.HAND_ACTUATORS[S.SVH_JOINT_NAMES.index(joint)]
    for name in (joint, f"svh_{joint}"):
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name) >= 0:
            return _qpos_adr(model, name)
    raise ConfigError(f"the episode's hand joint {joint!r} is not a joint of the pick scene")


def _arm_joints(episode: Episode, n: int) -> tuple[np.ndarray | None, str]:
    """(arm q (n, 6) rad or None, its source); /arm/joints is sampled at the step times by nearest earlier."""
    arm = episode.topics.get(S.TOPIC_ARM_JOINTS)
    if arm is not None and "position" in arm and len(arm["position"]):
        return np.asarray(arm["position"], float), S.TOPIC_ARM_JOINTS
    step = episode.topics.get(S.TOPIC_STEP, {})
    infos = [step.get(f"info.{j}") for j in names.ARM_JOINTS]
    if all(v is not None for v in infos):
        return np.stack([np.asarray(v, float).reshape(-1) for v in infos], axis=1), "/step infos arm_joint_1..6"
    return None, "not recorded"


def _at(times: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """``values`` of the last row logged at or before each time in ``at`` (the first row before any)."""
    k = np.clip(np.searchsorted(times, at, side="right") - 1, 0, len(values) - 1)
    return values[k]


def _rotations(xyzw: np.ndarray | None, n: int) -> np.ndarray:
    """(n, 3, 3) rotation matrices of quaternions x y z w (zero or missing: identity)."""
    if xyzw is None:
        return np.tile(np.eye(3), (n, 1, 1))
    q = np.asarray(xyzw, float).reshape(n, 4)
    q = np.where(np.linalg.norm(q, axis=1, keepdims=True) > 0, q, [0.0, 0.0, 0.0, 1.0])
    return Rotation.from_quat(q).as_matrix()


def scene_poses(model: mujoco.MjModel, episode: Episode, body_ids, opening_of_z=None,
                every: int = 1) -> ScenePoses | None:
    """Poses of ``body_ids`` per hand-joint step (see the module docstring); None without hand joints;
    a ``ConfigError`` for hand joints the model does not have.

    every: pose every ``every``-th step and the last one only (a dataset view's thinning).

    opening_of_z: (T, 2) latents -> (T,) hinge openings (rad) or None; reads leg b's angle off the
    recorded latent when the episode has no recorded hinge angle (real episodes)."""
    joints = episode.topics.get(S.TOPIC_JOINTS)
    if joints is None or len(joints.get("position", ())) == 0:
        return None
    all_steps = np.arange(len(joints["log_time_ns"]), dtype=np.int64)
    kept = all_steps[(all_steps % max(int(every), 1) == 0) | (all_steps == all_steps[-1])]
    times = np.asarray(joints["log_time_ns"], np.int64)[kept]
    n = len(times)
    joint_names = episode.metadata.get(S.KEY_JOINT_NAMES) or list(names.HAND_ACTUATORS)
    hand_adr = [_hand_qpos_adr(model, j) for j in joint_names]
    hand_q = np.asarray(joints["position"], float)[kept]
    data = mujoco.MjData(model)
    data.qpos[:] = model.key_qpos[model.key(names.GRASP_KEYFRAME).id]
    coupling = HandCoupling(model)
    arm_adr = [_qpos_adr(model, j) for j in names.ARM_JOINTS]
    arm_q, arm_source = _arm_joints(episode, n)
    if arm_q is not None:
        arm = episode.topics.get(S.TOPIC_ARM_JOINTS)
        if arm is not None:
            arm_q = _at(np.asarray(arm["log_time_ns"]), arm_q, times)
        else:  # step infos: one row per step
            arm_q = arm_q[np.minimum(kept, len(arm_q) - 1)]
    sources = {"hand": f"{S.TOPIC_JOINTS} through mj_kinematics",
               "arm": f"{arm_source} through mj_kinematics" if arm_q is not None else "not recorded: not drawn"}

    privileged = episode.topics.get(S.TOPIC_PRIVILEGED, {})
    tool_pos = tool_quat = None
    if "tool_position" in privileged and "tool_orientation" in privileged:
        pt = np.asarray(privileged["log_time_ns"])
        tool_pos = _at(pt, privileged["tool_position"], times)
        tool_quat = _at(pt, privileged["tool_orientation"], times)
        sources["tool"] = f"{S.TOPIC_PRIVILEGED} tool pose (body {names.TOOL_BODY_A})"
    elif S.TOPIC_TOOL_POSE in episode.topics:
        pose = episode.topics[S.TOPIC_TOOL_POSE]
        pt = np.asarray(pose["log_time_ns"])
        tool_pos, tool_quat = _at(pt, pose["position"], times), _at(pt, pose["orientation"], times)
        sources["tool"] = f"{S.TOPIC_TOOL_POSE} (registered)"
    else:
        sources["tool"] = "the grasp keyframe, in the hand"
    hinge = None
    latent = episode.topics.get(S.TOPIC_LATENT, {})
    if "hinge_angle" in privileged:
        hinge = _at(np.asarray(privileged["log_time_ns"]), np.asarray(privileged["hinge_angle"], float), times)
        sources["tool"] += ", hinge recorded"
    elif opening_of_z is not None and "z" in latent:
        z = latent.get("z_smoothed", latent["z"])
        opening = opening_of_z(np.asarray(z, float))
        if opening is not None:
            hinge = _at(np.asarray(latent["log_time_ns"]), np.asarray(opening, float).reshape(-1), times)
            sources["tool"] += ", hinge read off the latent (the encoder's calibration)"
    obj_pos = obj_quat = None
    if "object_position" in privileged:
        pt = np.asarray(privileged["log_time_ns"])
        obj_pos = _at(pt, privileged["object_position"], times)
        if "object_orientation" in privileged and np.shape(privileged["object_orientation"])[-1:] == (4,):
            obj_quat = _at(pt, privileged["object_orientation"], times)
        sources["object"] = f"{S.TOPIC_PRIVILEGED} object pose"
    elif S.TOPIC_OBJECT in episode.topics:
        topic = episode.topics[S.TOPIC_OBJECT]
        obj_pos = _at(np.asarray(topic["log_time_ns"]), topic["position"], times)
        sources["object"] = f"{S.TOPIC_OBJECT} (no orientation)"
    else:
        sources["object"] = "not recorded: not drawn"

    hand_body = model.body(names.HAND_BASE_BODY).id
    tool_free = _qpos_adr(model, names.TOOL_FREE_JOINT)
    hinge_adr = _qpos_adr(model, names.TOOL_HINGE)
    obj_free = _qpos_adr(model, names.OBJECT_FREE_JOINT)
    body_ids = np.asarray(body_ids, int)
    translation = np.empty((n, len(body_ids), 3))
    rotation = np.empty((n, len(body_ids), 3, 3))
    free_bodies = [(adr, pos, _rotations(quat, n)) for adr, pos, quat in
                   ((tool_free, tool_pos, tool_quat), (obj_free, obj_pos, obj_quat)) if pos is not None]
    world_quat = np.zeros(4)
    hand_rot = np.eye(3)
    for k in range(n):
        if arm_q is not None:
            data.qpos[arm_adr] = arm_q[k]
        data.qpos[hand_adr] = hand_q[k]
        coupling.apply_to_qpos(data)
        if hinge is not None:
            data.qpos[hinge_adr] = hinge[k]
        mujoco.mj_kinematics(model, data)  # the hand in the world first, to place the free bodies relative to it
        hand_pos, hand_rot = data.xpos[hand_body].copy(), data.xmat[hand_body].reshape(3, 3).copy()
        for adr, pos, rot in free_bodies:
            data.qpos[adr:adr + 3] = hand_pos + hand_rot @ pos[k]
            mujoco.mju_mat2Quat(world_quat, (hand_rot @ rot[k]).ravel())
            data.qpos[adr + 3:adr + 7] = world_quat
        mujoco.mj_kinematics(model, data)
        translation[k] = (data.xpos[body_ids] - hand_pos) @ hand_rot  # rows: R_hand^T (x - p_hand)
        rotation[k] = np.einsum("ji,bjk->bik", hand_rot, data.xmat[body_ids].reshape(-1, 3, 3))
    quaternion = Rotation.from_matrix(rotation.reshape(-1, 3, 3)).as_quat().reshape(n, len(body_ids), 4)  # x y z w
    return ScenePoses(body_ids, translation, quaternion, kept, times, arm_q is not None, sources)


def drawn(mesh: BodyMesh, poses: ScenePoses) -> bool:
    """Whether a body's mesh has a pose source in this episode (the arm and platform need arm joints)."""
    if mesh.part in ("arm", "scene"):
        return poses.has_arm
    if mesh.part == "object":
        return not poses.sources["object"].startswith("not recorded")
    return True


__all__ = ["BodyMesh", "ScenePoses", "scene_meshes", "scene_poses", "drawn", "WORLD_MESH"]

"""The robot in an episode's Rerun view: MJCF meshes posed every step, checked in the saved .rrd.

A real heuristic episode (``test_view_episode.write_heuristic_episode``: the sim's privileged body
poses, no arm joints) and a small trial-like episode (arm and hand joints and a registered tool pose,
no privileged state) are viewed with ``--save``; the .rrd is read back with Rerun's chunk reader and
checked by Rerun's own CLI (``rerun rrd verify``, ``rerun rrd stats``).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hingelab.episodes import EpisodeWriter, create_dataset, read_episode
from hingelab.perception.encoder import shipped_encoder
from hingelab.sim import names
from hingelab.sim.arm_kinematics import default_kinematics
from hingelab.sim.scene import load_scene
from hingelab.viewers import entities as E
from hingelab.viewers import view
from hingelab.viewers.scene_geometry import scene_meshes
from test_view_episode import rrd_tables, sorted_by, write_heuristic_episode

RERUN = shutil.which("rerun", path=str(Path(sys.executable).parent)) or shutil.which("rerun")


def _poses(tables, body: str) -> tuple[np.ndarray, np.ndarray]:
    """(translation (T, 3), rotation (T, 3, 3)) of ``world/robot/<body>`` per step, hand_base."""
    table = sorted_by(tables[f"/{E.ROBOT}/{body}"], E.TIMELINE_STEP)
    translation = np.array(table.column("Transform3D:translation").to_pylist()).reshape(-1, 3)
    quaternion = np.array(table.column("Transform3D:quaternion").to_pylist()).reshape(-1, 4)
    return translation, Rotation.from_quat(quaternion).as_matrix()


@pytest.fixture(scope="module")
def heuristic(tmp_path_factory):
    root = tmp_path_factory.mktemp("robot") / "heuristic"
    create_dataset(root, name="heuristic", source="heuristic", config={"test": "robot"}, seed=0)
    path = write_heuristic_episode(root, max_steps=30)
    rrd = root.parent / "heuristic.rrd"
    view(path, save=rrd, progress=False)
    return rrd, rrd_tables(rrd), read_episode(path)


@pytest.fixture(scope="module")
def trial(tmp_path_factory):
    """Six steps with arm joints, hand joints, a registered tool pose and a latent only (what a real trial has)."""
    root = tmp_path_factory.mktemp("robot") / "trial"
    create_dataset(root, name="trial", source="stand_in", config={"test": "robot"}, seed=0)
    model = load_scene("tool_pick")
    home = model.key_qpos[model.key(names.GRASP_KEYFRAME).id]
    arm_home = np.array([home[model.jnt_qposadr[model.joint(j).id]] for j in names.ARM_JOINTS])
    arm_q = arm_home + np.linspace(0.0, 0.2, 6)[:, None] * np.array([1, -1, 1, 0.5, -0.5, 1.0])
    openings = np.linspace(0.05, 0.25, len(arm_q))
    latents = shipped_encoder().calibration.z_for_opening(openings)
    with EpisodeWriter(root, source="stand_in", task="tool_pick", object="cube", seed=0) as writer:
        for k, q in enumerate(arm_q):
            writer.write_arm_joints(0.05 * k, names.ARM_JOINTS, q, np.zeros(6))
            writer.write_step(0.05 * k, joint_position=np.full(9, 0.1 * k / 6), joint_velocity=np.zeros(9),
                              latent_z=latents[k], latent_z_smoothed=latents[k],
                              tool_pose_hand=(np.array([0.035, 0.032, 0.122]), np.array([0.0, 1.0, 0.0, 0.0])),
                              object_position_hand=np.array([-0.15, 0.0, 0.12]))
        writer.set_outcome(success=False, failure_reason="timeout")
    rrd = root.parent / "trial.rrd"
    view(writer.path, save=rrd, progress=False)
    return rrd, rrd_tables(rrd), arm_q, openings


def test_scene_meshes_are_the_mjcf_geoms_in_body_frames():
    model = load_scene("tool_pick")
    meshes = {m.name: m for m in scene_meshes(model)}
    assert {"arm_link_2", "hand_base", "svh_index_t", "tool_leg_a", "tool_leg_b", "object", "world"} <= set(meshes)
    for mesh in meshes.values():
        assert mesh.triangles.max() < len(mesh.vertices) and len(mesh.colors) == len(mesh.vertices)
    platform = meshes["world"].vertices  # the platform box, 20 cm a side, top at z = 0.2 m (table left out)
    np.testing.assert_allclose(platform.min(axis=0), [0.4, -0.1, 0.0], atol=1e-6)
    np.testing.assert_allclose(platform.max(axis=0), [0.6, 0.1, 0.2], atol=1e-6)
    sphere = meshes["object"].vertices  # the training sphere, 2 cm across
    np.testing.assert_allclose(np.ptp(sphere, axis=0), [0.02] * 3, atol=1e-3)


def test_sim_episode_poses_come_from_the_recorded_bodies(heuristic):
    _, tables, episode = heuristic
    privileged = episode["/sim/privileged"]
    assert not any(key.startswith(f"/{E.ROBOT}/arm_") for key in tables), "no arm joints: no arm drawn"
    meshes = tables[f"/{E.ROBOT}/svh_index_t"].column("Mesh3D:vertex_positions").drop_null().to_pylist()
    assert len(meshes) == 1 and len(meshes[0]) > 100, "one static mesh per body"
    leg_a, rot_a = _poses(tables, names.TOOL_BODY_A)
    np.testing.assert_allclose(leg_a, privileged["tool_position"], atol=1e-6)
    obj, _ = _poses(tables, names.OBJECT_BODY)
    np.testing.assert_allclose(obj, privileged["object_position"], atol=1e-6)
    # the tips: the model's tip sites on the drawn legs land on the recorded tips (hinge angle included)
    model = load_scene("tool_pick")
    for site, tip in zip(names.TOOL_TIP_SITES, ("tip_a", "tip_b"), strict=True):
        body = model.body(model.site_bodyid[model.site(site).id]).name
        position, rotation = _poses(tables, body)
        drawn_tip = position + rotation @ model.site_pos[model.site(site).id]
        np.testing.assert_allclose(drawn_tip, privileged[tip], atol=1e-5)
    facts = tables["/" + E.FACTS].column("TextDocument:text").to_pylist()[0][0]
    assert "/sim/privileged tool pose" in facts and "not recorded" in facts


def test_trial_poses_come_from_the_arm_joints_through_kinematics(trial):
    _, tables, arm_q, openings = trial
    # the world (platform) seen from hand_base is the inverse of the hand's pose in the world
    rot, pos = default_kinematics().hand_poses(arm_q)
    world_t, world_r = _poses(tables, "world")
    np.testing.assert_allclose(world_t, -np.einsum("tji,tj->ti", rot, pos), atol=1e-6)
    np.testing.assert_allclose(world_r, np.transpose(rot, (0, 2, 1)), atol=1e-6)
    assert len(world_t) == len(arm_q) and f"/{E.ROBOT}/arm_link_3" in tables
    leg_a, rot_a = _poses(tables, names.TOOL_BODY_A)  # the registered tool pose
    np.testing.assert_allclose(leg_a, np.tile([0.035, 0.032, 0.122], (len(arm_q), 1)), atol=1e-6)
    np.testing.assert_allclose(rot_a, np.tile(np.diag([-1.0, 1.0, -1.0]), (len(arm_q), 1, 1)), atol=1e-6)
    _, rot_b = _poses(tables, names.TOOL_BODY_B)  # leg b opened by the opening read off the latent
    between = Rotation.from_matrix(np.einsum("tji,tjk->tik", rot_a, rot_b)).magnitude()
    np.testing.assert_allclose(between, openings, atol=0.01)
    facts = tables["/" + E.FACTS].column("TextDocument:text").to_pylist()[0][0]
    assert "/arm/joints through mj_kinematics" in facts and "read off the latent" in facts


def test_the_object_mesh_is_the_episodes_shape(trial, heuristic):
    for (_, tables, *_), extent, vertices in ((trial, [0.02] * 3, 8), (heuristic, [0.02] * 3, None)):
        mesh = np.array(tables[f"/{E.ROBOT}/object"].column("Mesh3D:vertex_positions").drop_null().to_pylist()[0])
        np.testing.assert_allclose(np.ptp(mesh, axis=0), extent, atol=1e-3)
        if vertices is not None:
            assert len(mesh) == vertices, "the trial's cube, not the scene's sphere"


def test_flange_meets_hand_base(trial):
    """The arm's last link is drawn where the hand hangs from it (the FK and the hand frame agree)."""
    _, tables, _, _ = trial
    model = load_scene("tool_pick")
    hand = model.body(names.HAND_BASE_BODY).id
    flange_t, flange_r = _poses(tables, model.body(model.body_parentid[hand]).name)
    offset = model.body_pos[hand]
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, model.body_quat[hand])
    np.testing.assert_allclose(flange_t + flange_r @ offset, 0.0, atol=1e-6)


@pytest.mark.skipif(RERUN is None, reason="the rerun executable of rerun-sdk is not on this environment's path")
@pytest.mark.parametrize("which", ["heuristic", "trial"])
def test_rrd_passes_rerun_verify_and_stats(which, request):
    """Rerun's own CLI reads the recording: it verifies, its stats list the meshes, its blueprint is the kind's."""
    rrd = request.getfixturevalue(which)[0]
    verify = subprocess.run([RERUN, "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=60)
    assert verify.returncode == 0, verify.stderr
    assert "verified without error" in verify.stdout + verify.stderr
    stats = subprocess.run([RERUN, "rrd", "stats", str(rrd)], capture_output=True, text=True, timeout=60)
    assert stats.returncode == 0, stats.stderr
    for entity in (f"/{E.ROBOT}/{names.TOOL_BODY_A}", f"/{E.ROBOT}/{names.TOOL_BODY_B}", f"/{E.ROBOT}/hand_base",
                   "/" + E.TOOL_FRAME):
        assert entity in stats.stdout, f"{entity} not in rerun rrd stats"
    printed = subprocess.run([RERUN, "rrd", "print", "-vvv", str(rrd)], capture_output=True, text=True, timeout=60)
    assert printed.returncode == 0 and f"episode ({which})" in printed.stdout, "the kind's layout"


def test_dataset_kinds_from_sources():
    from hingelab.viewers.blueprints import dataset_kind

    assert [dataset_kind(s) for s in ("heuristic", "scripted", "low_level_evaluation", "low_level_training",
                                      "high_level_evaluation", "flat_training", "stand_in", "real", "bench", None)] == [
        "heuristic", "heuristic", "low_level", "low_level", "high_level", "high_level", "trial", "real", "generic",
        "generic"]


def _static(tables, entity: str, column: str):
    values = tables["/" + entity].column(column).drop_null().to_pylist()
    assert len(values) == 1, f"{entity} {column}: one static value"
    return values[0]


def test_markers_are_sized_in_metres_and_tip_labels_stay_hidden(heuristic):
    _, tables, _ = heuristic
    assert _static(tables, E.TIPS, "Points3D:radii") == pytest.approx([0.0015])  # a 3 mm dot per tip
    assert _static(tables, E.TARGET, "Points3D:radii") == pytest.approx([0.0025])
    assert _static(tables, E.OBJECT, "Points3D:radii") == pytest.approx([0.010])  # the 2 cm sphere's radius
    assert _static(tables, E.TIPS, "Points3D:show_labels") == [False]
    assert _static(tables, E.OBJECT, "Points3D:show_labels") == [True]


def test_latent_plane_is_framed_to_the_reachable_region(heuristic):
    from hingelab.viewers.latent_frame import reachable_latent_curve
    from hingelab.viewers.view import _episode_plane_bounds

    _, tables, episode = heuristic
    curve = reachable_latent_curve()
    assert curve is not None and curve.shape == (64, 2)
    logged = _static(tables, E.PLANE_REACHABLE, "LineStrips2D:strips")[0]
    np.testing.assert_allclose(np.array(logged), curve, atol=1e-6)
    (x0, x1), (y0, y1) = _episode_plane_bounds(episode)
    assert x1 - x0 == pytest.approx(y1 - y0) and x1 - x0 < 6.0, "square, tighter than the prior's [-3, 3]^2"
    for points in (curve, episode["/tool/latent"]["z"], episode["/goal"]["z_goal"]):
        assert (points[:, 0] >= x0).all() and (points[:, 0] <= x1).all()
        assert (points[:, 1] >= y0).all() and (points[:, 1] <= y1).all()


def test_real_import_poses_the_arm_from_its_step_infos(tmp_path):
    """A real import keeps the arm's angles as step infos ``arm_joint_1..6``, not on /arm/joints."""
    root = tmp_path / "real"
    create_dataset(root, name="real", source="real", config={"test": "robot"}, seed=0)
    model = load_scene("tool_pick")
    home = model.key_qpos[model.key(names.GRASP_KEYFRAME).id]
    arm_q = np.array([home[model.jnt_qposadr[model.joint(j).id]] for j in names.ARM_JOINTS]) + np.array(
        [[0.0] * 6, [0.1, -0.1, 0.1, 0.0, 0.0, 0.2]])
    with EpisodeWriter(root, source="real", task="tool_pick", object="sphere", seed=0) as writer:
        for k, q in enumerate(arm_q):
            writer.write_step(0.05 * k, joint_position=np.zeros(9), joint_velocity=np.zeros(9),
                              tool_pose_hand=(np.array([0.035, 0.032, 0.122]), np.array([0.0, 1.0, 0.0, 0.0])),
                              transition={"observation": np.zeros(3), "action": np.zeros(5), "reward": 0.0,
                                          "terminated": False, "truncated": False,
                                          "info": dict(zip(names.ARM_JOINTS, map(float, q), strict=True))})
        writer.set_outcome(success=False, failure_reason="timeout")
    rrd = tmp_path / "real.rrd"
    view(writer.path, save=rrd, progress=False)
    tables = rrd_tables(rrd)
    rot, pos = default_kinematics().hand_poses(arm_q)
    world_t, _ = _poses(tables, "world")
    np.testing.assert_allclose(world_t, -np.einsum("tji,tj->ti", rot, pos), atol=1e-6)
    facts = tables["/" + E.FACTS].column("TextDocument:text").to_pylist()[0][0]
    assert "/step infos arm_joint_1..6" in facts and "not recorded: not drawn" in facts  # no object recorded


def test_an_unknown_hand_leaves_the_scene_out_and_says_why(tmp_path):
    root = tmp_path / "other"
    create_dataset(root, name="other", source="real", config={"test": "robot"}, seed=0)
    with EpisodeWriter(root, source="real", task="tool_pick", object="sphere", seed=0,
                       joint_names=[f"other_{i}" for i in range(9)]) as writer:
        writer.write_step(0.0, joint_position=np.zeros(9), joint_velocity=np.zeros(9))
        writer.set_outcome(success=False, failure_reason="timeout")
    rrd = tmp_path / "other.rrd"
    view(writer.path, save=rrd, progress=False)
    tables = rrd_tables(rrd)
    assert not any(key.startswith(f"/{E.ROBOT}/") for key in tables)
    facts = tables["/" + E.FACTS].column("TextDocument:text").to_pylist()[0][0]
    assert "not drawn: the episode's hand joint 'other_0' is not a joint of the pick scene" in facts

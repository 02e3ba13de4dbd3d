"""Model lint: every scene loads, steps under random controls without MuJoCo warnings,
names every element, and exposes the public interface other issues rely on."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from hingelab.paths import ASSETS_DIR, SCENES_DIR
from hingelab.sim import names
from hingelab.sim.scene import load_scene

PART_FILES = [ASSETS_DIR / "svh_hand" / "svh_hand.xml", ASSETS_DIR / "jaka_zu7" / "jaka_zu7.xml",
              ASSETS_DIR / "tweezer" / "tweezer.xml"]
SCENE_FILES = [SCENES_DIR / "tool_shape.xml", SCENES_DIR / "tool_pick.xml"]


@pytest.mark.parametrize("path", PART_FILES + SCENE_FILES, ids=lambda p: p.name)
def test_model_steps_one_second_of_random_control_without_warnings(path):
    model = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(model)
    if model.nkey:
        mujoco.mj_resetDataKeyframe(model, data, 0)
    rng = np.random.default_rng(0)
    low, high = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    for step in range(int(1.0 / model.opt.timestep)):
        if step % 25 == 0:  # a new random target every control period
            data.ctrl[:] = data.ctrl + 0.05 * (rng.uniform(low, high) - data.ctrl)
        mujoco.mj_step(model, data)
    assert [w.number for w in data.warning] == [0] * len(data.warning)
    assert np.isfinite(data.qpos).all()


@pytest.mark.parametrize("path", SCENE_FILES, ids=lambda p: p.name)
def test_every_element_is_named(path):
    model = mujoco.MjModel.from_xml_path(str(path))
    for kind, count in [("body", model.nbody), ("joint", model.njnt), ("actuator", model.nu),
                        ("site", model.nsite), ("equality", model.neq), ("geom", model.ngeom)]:
        unnamed = [i for i in range(count) if not getattr(model, kind)(i).name]
        if kind == "body":
            unnamed = [i for i in unnamed if i != 0]  # the world body
        assert not unnamed, f"{path.name}: unnamed {kind} ids {unnamed}"


@pytest.mark.parametrize("scene", names.SCENES)
def test_public_interface(scene):
    model = load_scene(scene)
    joints = [model.joint(i).name for i in range(model.njnt)]
    assert len([j for j in joints if j.startswith("svh_")]) == 20
    assert [model.actuator(a).name for a in names.HAND_ACTUATORS] == list(names.HAND_ACTUATORS)
    for body in (names.HAND_BASE_BODY, names.TOOL_BODY_A, names.TOOL_BODY_B):
        model.body(body)
    assert model.jnt_type[model.joint(names.TOOL_HINGE).id] == mujoco.mjtJoint.mjJNT_HINGE
    for site in names.TOOL_TIP_SITES:
        model.site(site)
    model.key(names.GRASP_KEYFRAME)
    if scene == "tool_pick":
        assert [j for j in joints if j.startswith("arm_")] == list(names.ARM_JOINTS)
        model.body(names.OBJECT_BODY)


def test_hand_couplings_are_the_real_ones():
    model = load_scene("tool_shape")
    expected = {"svh_palm_j5": ("svh_thumb_opposition", 1.0), "svh_thumb_j3": ("svh_thumb_flexion", 1.01511),
                "svh_thumb_j4": ("svh_thumb_flexion", 1.44889), "svh_index_j14": ("svh_index_distal", 1.0450),
                "svh_middle_j15": ("svh_middle_distal", 1.0454), "svh_ring_j12": ("svh_ring", 1.3588),
                "svh_ring_j16": ("svh_ring", 1.42093), "svh_pinky_j13": ("svh_pinky", 1.35880),
                "svh_pinky_j17": ("svh_pinky", 1.42307), "svh_index_spread": ("svh_spread", 0.5),
                "svh_ring_spread": ("svh_spread", 0.5)}
    found = {}
    for i in range(model.neq):
        assert model.eq_type[i] == mujoco.mjtEq.mjEQ_JOINT, "only joint couplings: nothing may weld the tool"
        dep, prim = model.joint(model.eq_obj1id[i]), model.joint(model.eq_obj2id[i])
        found[dep.name] = (prim.name, float(model.eq_data[i][1]))
        # the dependent's range is k times the primary's, so the coupling never fights a limit
        assert dep.range[1] == pytest.approx(found[dep.name][1] * prim.range[1], rel=2e-3)
    assert found.keys() == expected.keys()
    for dep, (prim, k) in expected.items():
        assert found[dep][0] == prim and found[dep][1] == pytest.approx(k)


def test_tool_is_a_free_body_held_by_contact():
    model = load_scene("tool_pick")
    free = model.joint(names.TOOL_FREE_JOINT)
    assert model.jnt_type[free.id] == mujoco.mjtJoint.mjJNT_FREE
    assert model.body(names.TOOL_BODY_A).parentid == 0  # child of the world, not of the hand
    tool_mass = float(model.body(names.TOOL_BODY_A).mass[0] + model.body(names.TOOL_BODY_B).mass[0])
    assert 0.015 < tool_mass < 0.040  # a 13 cm tweezer printed in PLA: tens of grams
    hinge_servo = model.actuator(names.TOOL_HINGE_ACTUATOR).id
    assert model.actuator_gainprm[hinge_servo, 0] == 0.0  # off unless the privileged command is used


def test_arm_kinematics_match_the_urdf():
    model = mujoco.MjModel.from_xml_path(str(ASSETS_DIR / "jaka_zu7" / "jaka_zu7.xml"))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(data.site("arm_flange_site").xpos, [0.6635, 0.0080, 0.0067], atol=2e-4)
    data.joint("arm_joint_2").qpos = data.joint("arm_joint_4").qpos = np.pi / 2
    mujoco.mj_forward(model, data)
    assert data.site("arm_flange_site").xpos[2] == pytest.approx(0.897, abs=1e-3)


def test_hand_fingertips_match_the_svh_description():
    model = mujoco.MjModel.from_xml_path(str(ASSETS_DIR / "svh_hand" / "svh_hand.xml"))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    expected = {"svh_thumb_tip": (-0.105, 0.041, 0.102), "svh_index_tip": (-0.025, -0.013, 0.207),
                "svh_middle_tip": (0.0, -0.013, 0.214), "svh_ring_tip": (0.022, -0.013, 0.207),
                "svh_pinky_tip": (0.044, -0.013, 0.182)}
    for site, pos in expected.items():
        np.testing.assert_allclose(data.site(site).xpos, pos, atol=2e-3)

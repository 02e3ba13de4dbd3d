"""Builds the two task scenes from the part models and settles the ``grasp`` keyframe.

    python -m hingelab.sim.scene_builder      # rewrites assets/scenes/*.xml and grasp_synergy.json

The parts (assets/svh_hand, jaka_zu7, tweezer) are the hand-written model files; the
scenes are generated from them with MjSpec so that the hand can hang from a fixed mount
or from the arm's flange with the same names. The ``grasp`` keyframe is found by
physics, not written by hand: the tool is placed on the palm rest with leg b at
``GRASP_THETA``, the fingers close onto it with the synergy's targets, and the state
after ``SETTLE_S`` seconds is stored. Run it again after changing a part.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import warnings
from pathlib import Path

import mujoco
import numpy as np

from hingelab.errors import ConfigError
from hingelab.json_text import strict_dumps
from hingelab.paths import ASSETS_DIR, SCENES_DIR, refuse_to_replace_shipped
from hingelab.provenance import code_version
from hingelab.sim import names
from hingelab.sim.arm_control import solve_hand_pose
from hingelab.sim.finger_synergy import FingerSynergy, SynergyFitter
from hingelab.sim.hand import HandCoupling
from hingelab.sim.objects import TRAINING_OBJECT, ObjectSpec, add_object_geom

TIMESTEP = 0.002  # s; 25 physics steps per 20 Hz control step
# hand_base in the world for the tool_shape scene and at the pick scene's home: the
# tweezer tips point down (hand -x = world -z), the fingers point along world +x.
HAND_ROT_WORLD = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])
SHAPE_HAND_POS = np.array([0.0, 0.0, 0.5])
# The tool frame in hand_base: hinge on the ulnar side, legs across the palm toward
# the thumb side, leg b opening away from the palm (+y of the hand).
TOOL_POS_HAND = np.array([0.035, 0.032, 0.122])
TOOL_ROT_HAND = np.diag([-1.0, 1.0, -1.0])
GRASP_THETA = 0.15  # rad: hinge angle the grasp is set up at (mid-range)
SETTLE_S = 1.5
CALIBRATE_S = 1.0
SYNERGY_THETAS = np.round(np.arange(0.0, 0.3001, 0.02), 4)

# Pick scene layout (metres, world frame; the table top is z = 0).
PLATFORM_CENTER = np.array([0.50, 0.0])
PLATFORM_HEIGHT = 0.20
PLATFORM_HALF = 0.10  # a 20 x 20 cm top
HOME_TIP_HEIGHT = 0.08  # tips above the platform top at home


def _quat(rot: np.ndarray) -> list[float]:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.asarray(rot, float).ravel())
    return q.tolist()


def _load_part(name: str, file: str) -> mujoco.MjSpec:
    path = ASSETS_DIR / name / file
    return mujoco.MjSpec.from_file(str(path))


@contextlib.contextmanager
def _empty_prefix_attach_allowed():
    # An empty prefix keeps the public names (svh_*, tool_*); MuJoCo warns that such a
    # spec may not save, which is why the saved scenes are re-loaded and checked by tests.
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Attaching a spec with an empty prefix")
        yield


def _attach(frame: mujoco.MjsFrame, part: mujoco.MjSpec) -> None:
    with _empty_prefix_attach_allowed():
        frame.attach_body(part.worldbody.first_body(), "", "")


def _compile(spec: mujoco.MjSpec) -> mujoco.MjModel:
    with _empty_prefix_attach_allowed():
        return spec.compile()


def _to_xml(spec: mujoco.MjSpec) -> str:
    with _empty_prefix_attach_allowed():
        return spec.to_xml()


def _base_spec(model_name: str) -> mujoco.MjSpec:
    spec = mujoco.MjSpec()
    spec.modelname = model_name
    spec.compiler.degree = False
    spec.option.timestep = TIMESTEP
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = 30  # elliptic cones + impratio ~30 held the tweezer best (ECOSYSTEM.md)
    spec.visual.headlight.ambient = [0.4, 0.4, 0.4]
    spec.visual.headlight.diffuse = [0.6, 0.6, 0.6]
    spec.worldbody.add_light(name="key_light", pos=[0.3, -0.6, 1.5], dir=[-0.2, 0.5, -1.0])
    return spec


def _add_tool(spec: mujoco.MjSpec, hand_pos: np.ndarray, hand_rot: np.ndarray) -> None:
    pos = hand_pos + hand_rot @ TOOL_POS_HAND
    frame = spec.worldbody.add_frame(pos=pos.tolist(), quat=_quat(hand_rot @ TOOL_ROT_HAND))
    _attach(frame, _load_part("tweezer", "tweezer.xml"))


def tool_shape_spec() -> mujoco.MjSpec:
    """Hand with its base fixed in space, tweezer in hand: the low-level task."""
    spec = _base_spec("tool_shape")
    spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[1, 1, 0.05],
                            rgba=[0.3, 0.32, 0.35, 1])
    mount = spec.worldbody.add_body(name="hand_mount", pos=SHAPE_HAND_POS.tolist(), quat=_quat(HAND_ROT_WORLD))
    _attach(mount.add_frame(), _load_part("svh_hand", "svh_hand.xml"))
    _add_tool(spec, SHAPE_HAND_POS, HAND_ROT_WORLD)
    return spec


def tool_pick_spec() -> mujoco.MjSpec:
    """Table, 20 cm platform, arm, hand, tweezer and the training sphere: the high-level task."""
    spec = _base_spec("tool_pick")
    spec.worldbody.add_geom(name="table", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.6, 0.6, 0.02],
                            pos=[0.3, 0, -0.02], rgba=[0.55, 0.45, 0.35, 1], friction=[0.8, 0.01, 0.0001])
    spec.worldbody.add_geom(name="platform", type=mujoco.mjtGeom.mjGEOM_BOX,
                            size=[PLATFORM_HALF, PLATFORM_HALF, PLATFORM_HEIGHT / 2],
                            pos=[*PLATFORM_CENTER, PLATFORM_HEIGHT / 2], rgba=[0.8, 0.8, 0.75, 1],
                            friction=[0.8, 0.01, 0.0001])
    arm_frame = spec.worldbody.add_frame(pos=[0, 0, 0])
    _attach(arm_frame, _load_part("jaka_zu7", "jaka_zu7.xml"))
    flange = spec.body("arm_flange")
    # hand_base on the flange: hand +z (fingers) along the flange's tool axis
    _attach(flange.add_frame(pos=[0, 0, 0.0]), _load_part("svh_hand", "svh_hand.xml"))
    # the arm controller compensates its payload: the hand's weight (not the tool's)
    for body in spec.bodies:
        if body.name == names.HAND_BASE_BODY or body.name.startswith("svh_"):
            body.gravcomp = 1
    _add_tool(spec, SHAPE_HAND_POS, HAND_ROT_WORLD)  # re-posed by the keyframe
    shape, size, mass = TRAINING_OBJECT
    obj = ObjectSpec(shape, size, mass)
    body = spec.worldbody.add_body(name=names.OBJECT_BODY,
                                   pos=[*PLATFORM_CENTER, PLATFORM_HEIGHT + obj.rest_height])
    body.add_freejoint(name=names.OBJECT_FREE_JOINT)
    add_object_geom(spec, body, obj)
    spec.worldbody.add_site(name="target", pos=[*PLATFORM_CENTER, PLATFORM_HEIGHT + 0.06], size=[0.006, 0, 0],
                            rgba=[0.4, 0.7, 1.0, 0.5], group=2)
    return spec


def _place_tool_in_hand(model, data, theta: float) -> None:
    hb = data.body(names.HAND_BASE_BODY)
    rot_h = hb.xmat.reshape(3, 3)
    pos = hb.xpos + rot_h @ TOOL_POS_HAND
    adr = model.jnt_qposadr[model.joint(names.TOOL_FREE_JOINT).id]
    data.qpos[adr:adr + 3] = pos
    data.qpos[adr + 3:adr + 7] = _quat(rot_h @ TOOL_ROT_HAND)
    data.joint(names.TOOL_HINGE).qpos = theta
    data.qvel[:] = 0


def _set_hand(model, data, targets: np.ndarray) -> None:
    for name, value in zip(names.HAND_ACTUATORS, targets):
        data.joint(name).qpos = value
    _set_hand_ctrl(data, targets)
    HandCoupling(model).apply_to_qpos(data)


def _settle(model, data, seconds: float) -> None:
    for _ in range(int(round(seconds / model.opt.timestep))):
        mujoco.mj_step(model, data)
    data.qvel[:] = 0
    mujoco.mj_forward(model, data)


def settle_grasp(model: mujoco.MjModel, data: mujoco.MjData, synergy=None):
    """Place the tool on the palm, close the fingers on it and settle; returns the synergy used."""
    mujoco.mj_forward(model, data)
    _place_tool_in_hand(model, data, GRASP_THETA)
    mujoco.mj_forward(model, data)
    if synergy is None:
        # first pass: fit on the nominal placement, settle, then refit on the settled pose
        synergy = SynergyFitter(model, data).fit(SYNERGY_THETAS)
        _set_hand(model, data, synergy.targets(GRASP_THETA))
        _settle(model, data, SETTLE_S)
        synergy = SynergyFitter(model, data).fit(SYNERGY_THETAS)
    _set_hand(model, data, synergy.targets(GRASP_THETA))
    _settle(model, data, SETTLE_S)
    return synergy


def calibrate_synergy(model: mujoco.MjModel, grasp_qpos: np.ndarray, synergy: FingerSynergy) -> FingerSynergy:
    """Re-key the synergy by the hinge angle its targets really reach.

    The fitted table is kinematic; under contact the leg settles a little closed of its
    row's angle. Each row is run from the settled grasp for CALIBRATE_S and the measured
    hinge angle becomes its key, so that ``targets(theta)`` means "reach theta".
    """
    data = mujoco.MjData(model)
    measured = []
    for row in synergy.targets_table:
        data.qpos[:] = grasp_qpos
        data.qvel[:] = 0
        data.time = 0
        _set_hand_ctrl(data, row)
        _settle(model, data, CALIBRATE_S)
        measured.append(float(data.joint(names.TOOL_HINGE).qpos[0]))
    measured = np.asarray(measured)
    keep = [0]
    for k in range(1, len(measured)):  # keep a strictly increasing key
        if measured[k] > measured[keep[-1]] + 1e-3:
            keep.append(k)
    return FingerSynergy(measured[keep], synergy.targets_table[keep])


def _set_hand_ctrl(data, targets: np.ndarray) -> None:
    for name, value in zip(names.HAND_ACTUATORS, targets):
        data.actuator(name).ctrl = value


def _add_keyframe(spec: mujoco.MjSpec, model, data) -> None:
    spec.add_key(name=names.GRASP_KEYFRAME, time=0.0, qpos=data.qpos.tolist(),
                 qvel=[0.0] * model.nv, ctrl=data.ctrl.tolist())


def _home_arm(model, data) -> np.ndarray:
    """Arm joints with the tweezer tips HOME_TIP_HEIGHT above the platform centre."""
    tips_in_hand = TOOL_POS_HAND + TOOL_ROT_HAND @ np.array([0.124, 0.0, 0.0])
    tips_world = np.array([*PLATFORM_CENTER, PLATFORM_HEIGHT + HOME_TIP_HEIGHT])
    hand_pos = tips_world - HAND_ROT_WORLD @ tips_in_hand
    # elbow up, forearm reaching forward and down over the platform
    seed = dict(zip(names.ARM_JOINTS, (-0.3, 1.7, -1.7, 0.0, -1.9, 1.57)))
    for joint, value in seed.items():
        data.joint(joint).qpos = value
    return solve_hand_pose(model, data, hand_pos, HAND_ROT_WORLD)


def build(out_dir: Path = SCENES_DIR) -> dict:
    """Write tool_shape.xml, tool_pick.xml and grasp_synergy.json; return a summary."""
    out_dir.mkdir(parents=True, exist_ok=True)
    summary = {}

    spec = tool_shape_spec()
    model = _compile(spec)
    data = mujoco.MjData(model)
    fitted = settle_grasp(model, data)
    _add_keyframe(spec, model, data)
    synergy = calibrate_synergy(model, data.qpos.copy(), fitted)
    (out_dir / "tool_shape.xml").write_text(_header("tool_shape") + _to_xml(spec))
    summary["tool_shape_hinge"] = float(data.joint(names.TOOL_HINGE).qpos[0])

    spec = tool_pick_spec()
    model = _compile(spec)
    data = mujoco.MjData(model)
    q_home = _home_arm(model, data)
    for joint, value in zip(names.ARM_JOINTS, q_home):
        data.joint(joint).qpos = value
        data.actuator(joint).ctrl = value
    settle_grasp(model, data, fitted)
    _add_keyframe(spec, model, data)
    (out_dir / "tool_pick.xml").write_text(_header("tool_pick") + _to_xml(spec))
    summary["tool_pick_hinge"] = float(data.joint(names.TOOL_HINGE).qpos[0])
    summary["arm_home"] = q_home.round(4).tolist()
    summary["synergy_hinge_range"] = list(synergy.theta_range)

    payload = {**synergy.to_json(), "made_by": "python -m hingelab.sim.scene_builder", **code_version()}
    (out_dir / "grasp_synergy.json").write_text(strict_dumps(payload, out_dir / "grasp_synergy.json", indent=1) + "\n")
    return summary


def _header(name: str) -> str:
    return (f"<!-- {name}: GENERATED by `python -m hingelab.sim.scene_builder` from assets/svh_hand, "
            "jaka_zu7, tweezer and objects; edit the parts and rebuild, not this file. -->\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=SCENES_DIR,
                        help=f"folder for the scene files (default {SCENES_DIR})")
    parser.add_argument("--force", action="store_true",
                        help="replace the shipped scenes under assets/ (shipped policies were trained in them)")
    args = parser.parse_args()
    try:
        refuse_to_replace_shipped(args.out / "tool_shape.xml", args.force)
    except ConfigError as exc:
        parser.exit(1, f"{parser.prog}: error: {exc}\n")
    print(json.dumps(build(args.out), indent=1))


if __name__ == "__main__":
    main()

"""A rig bag recorded on the simulator: what ``ros2 bag record`` would write if ToolPick-v0 were the rig.

``write_sim_rig_bag(path, SimRigBagSpec(...))`` runs the privileged heuristic on ToolPick-v0 (one
trial per episode) and writes, through ``rosbags``' writer, the topics a lab records on the real rig
(README, "Real-robot logs"), each from the simulator's state at every 20 Hz control step:

- ``/joint_states``: arm_joint_1..6 (the sim's arm joint angles) and the hand's 9 channels;
- ``/tf``: world -> hand_base (the hand's pose, as the arm driver's TF tree gives it), and
  ``/tf_static``: world -> camera_link -> camera_depth_optical_frame (a camera fixed in the world);
- ``/camera/depth/points``: the tweezer's surface sampled at its simulated pose and opening
  (``CloudSynthesizer``, ``camera_noise_m`` per point, no calibration offset), in the camera frame;
  or (``camera="depth"``) the stand-in's camera: the rig camera's rendered depth image of the whole scene
  (tool, hand, object, platform, table; ``hingelab.sim.rig_camera``, with the camera path's depth noise)
  on ``/camera/depth/image_raw`` with its ``/camera/depth/camera_info``, the camera's true pose on
  ``/tf_static``; or (``camera="points"``) the same frames as a whole-scene PointCloud2 (every pixel with a
  return); with ``object_mask`` the object's pixels (the simulator's segmentation, mono8) on
  ``/camera/depth/object_mask``, stamped as their image. ``hidden_object_steps``: frames whose object
  pixels give no return (and an empty mask): the object unseen, as behind the tool or out of view;
- ``/object/pose``: the object's centre (world), as a detector would report it;
- ``/hingelab/action``: the high-level action the step executed (the heuristic's, as the env reports
  it: the reached latent / 3 and the commanded hand velocity / 0.08), published at the step's start;
- ``/trial/event``: ``start`` at the first state, ``success`` at the first successful state (or
  ``failure:<reason>``), ``end`` at the last.

Header stamps are the states' simulated times (from ``T0_NS``); log times follow by a driver's
latency. It returns the simulator's truth per trial (the env's rewards and terms, successes, the
executed actions, the object's true centre), which the imported and relabelled episodes are compared
against (tests/test_real_demos.py, tests/test_ros2_object_from_cloud.py): the real path's rewards and
object estimates come from perception and kinematics, these from privileged state. A rendered camera
keeps every frame in memory until the bag is written (1.5 MB each): it is for short trials.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from hingelab.envs import TOOL_PICK_ID
from hingelab.errors import ConfigError
from hingelab.heuristic.controller import PrivilegedHeuristic
from hingelab.perception.camera_cloud import depth_to_points
from hingelab.perception.clouds import CloudRealism, CloudSynthesizer
from hingelab.ros2.rig_bag import (
    CAMERA_IN_WORLD,
    CAMERA_OPTICAL,
    T0_NS,
    _header,
    _tf,
    camera_info_message,
    image_message,
    point_cloud2,
)
from hingelab.ros2.topics import ARM_JOINT_NAMES, HAND_JOINTS, KINDS
from hingelab.seeds import demo_seed
from hingelab.sim import names
from hingelab.sim.finger_synergy import FingerSynergy
from hingelab.sim.rig_camera import camera_pose_world

STEP_S = 0.05


@dataclass
class SimRigBagSpec:
    episodes: int = 1
    seed: int = 0
    object: str = "sphere"
    size: float = 0.02
    randomize: bool = False
    max_episode_steps: int = 200
    camera_points: int = 1024  # tool points per camera frame (before the pipeline's 2 mm voxels)
    camera_noise_m: float = 0.001  # per-point depth noise
    object_pose: bool = True  # write /object/pose (a rig without an object detector: False)
    gap_s: float = 0.5  # before and between trials
    camera: str = "synthesized"  # or "depth", "points": the rig camera's rendered frames (module docstring)
    object_mask: bool = False  # with camera "depth": the object's pixels on /camera/depth/object_mask
    hidden_object_steps: tuple = ()  # (trial, state index) pairs whose rendered frame does not see the object

    def __post_init__(self):
        if self.camera not in CAMERAS:
            raise ConfigError(f"camera {self.camera!r} is unknown; choose one of {', '.join(CAMERAS)}")
        if self.object_mask and self.camera != "depth":
            raise ConfigError("object_mask segments the depth image: it needs camera 'depth'")


CAMERAS = ("synthesized", "depth", "points")


def _snapshot(pick, rendered: bool) -> dict:
    """The state a rig's drivers would publish now (world = the arm's base frame); with a rendered camera, the
    frame the env's camera path rendered of it (noisy depth, metres) and the object's pixels."""
    d, s = pick.sim.data, pick.state
    hand = pick.sim.reader.hand_body
    snapshot = {"arm_q": np.array([d.joint(j).qpos[0] for j in names.ARM_JOINTS]),
                "hand_q": pick.sim.hand.q(d).copy(), "hand_qdot": pick.sim.hand.qdot(d).copy(),
                "hand_rot": d.xmat[hand].reshape(3, 3).copy(), "hand_pos": d.xpos[hand].copy(),
                "tool_pos": s.tool_pos_hand.copy(), "tool_quat": s.tool_quat_hand.copy(), "hinge": s.hinge_angle,
                "object": pick.observed_object_centre().copy()}
    if rendered:
        camera = pick.perception.camera  # this step's render (the one the env's tool perception made)
        object_geoms = np.flatnonzero(pick.sim.model.geom_bodyid == pick.sim.model.body(names.OBJECT_BODY).id)
        snapshot.update(depth=camera.frame.depth.astype(np.float32, copy=True),
                        object_mask=np.isin(camera.geoms, object_geoms))
    return snapshot


def _run_trial(env, seed: int, rendered: bool) -> dict:
    env.reset(seed=seed)
    pick = env.unwrapped
    heuristic = PrivilegedHeuristic(pick.sim, FingerSynergy.load(), pick.object)
    heuristic.reset(pick.state, pick.target)
    states, rewards, terms, actions, success, collisions = [_snapshot(pick, rendered)], [], [], [], [], []
    info = {}
    while True:
        command = heuristic.act(pick.state)
        pick.command_privileged(command.arm_velocity, command.hinge_target, command.hand_targets)
        _, reward, terminated, truncated, info = env.step(np.zeros(5))
        states.append(_snapshot(pick, rendered))
        rewards.append(reward)
        terms.append(dict(info["reward_terms"]))
        actions.append(np.asarray(info["executed_action"], float))
        success.append(bool(info["is_success"]))
        collisions.append(bool(info["table_collision"]))
        if terminated or truncated:
            break
    return {"states": states, "rewards": np.array(rewards), "actions": np.array(actions),
            "terms": {k: np.array([t[k] for t in terms]) for k in terms[0]}, "is_success": np.array(success),
            "table_collision": np.array(collisions), "success": bool(info.get("is_success", 0.0)),
            "failure_reason": info.get("failure_reason"), "target_world": pick.target.copy(), "seed": seed}


def write_sim_rig_bag(path, spec: SimRigBagSpec = SimRigBagSpec()) -> dict:
    """Run ``spec.episodes`` heuristic trials and write them as one rig bag (rosbag2 folder, MCAP storage).

    Returns ``{"trials": [...]}``: per trial its start (ns), the env's per-step ``rewards`` (T,),
    ``terms``, ``actions`` (T, 5), ``is_success`` (T,), ``table_collision`` (T,), ``success``,
    ``target_world`` and the T + 1 simulated ``states`` it published (each with ``object``, the object's
    true centre in the world, m)."""
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    synth = CloudSynthesizer(realism=CloudRealism(noise_std_m=spec.camera_noise_m, removal_fraction=0.0,
                                                  max_angle_rad=0.0, max_offset_m=0.0),
                             seed=spec.seed, n_points=spec.camera_points)
    synth.new_episode(spec.seed)
    rendered = spec.camera != "synthesized"
    env = gym.make(TOOL_PICK_ID, object=spec.object, size=spec.size, randomize=spec.randomize,
                   max_episode_steps=spec.max_episode_steps, low_level="privileged",
                   perception="camera" if rendered else "synthesized")
    try:
        trials = [_run_trial(env, demo_seed(spec.seed, i), rendered) for i in range(spec.episodes)]
        pick = env.unwrapped
        intrinsics = pick.perception.camera.intrinsics if rendered else None
        cam_rot, cam_pos = camera_pose_world(pick.sim.model, pick.sim.data) if rendered else CAMERA_IN_WORLD
    finally:
        env.close()
    messages = []  # (log ns, order, topic, message)

    def add(log_ns, topic, msg):
        messages.append((int(log_ns), len(messages), topic, msg))

    add(T0_NS, "/tf_static", T["tf2_msgs/msg/TFMessage"](transforms=[
        _tf(ts, T0_NS, "world", "camera_link", cam_rot, cam_pos),
        _tf(ts, T0_NS, "camera_link", CAMERA_OPTICAL, np.eye(3), np.zeros(3))]))
    start_s = spec.gap_s
    hidden = {tuple(pair) for pair in spec.hidden_object_steps}
    for index, trial in enumerate(trials):
        start = T0_NS + round(start_s * 1e9)
        trial["start_ns"] = start
        stamps = start + np.arange(len(trial["states"])) * round(STEP_S * 1e9)
        for k, (t, s) in enumerate(zip(stamps, trial["states"])):
            add(t + 1_000_000, "/tf", T["tf2_msgs/msg/TFMessage"](
                transforms=[_tf(ts, t, "world", names.HAND_BASE_BODY, s["hand_rot"], s["hand_pos"])]))
            add(t + 2_000_000, "/joint_states", T["sensor_msgs/msg/JointState"](
                header=_header(ts, t), name=list(ARM_JOINT_NAMES) + list(HAND_JOINTS),
                position=np.concatenate([s["arm_q"], s["hand_q"]]),
                velocity=np.concatenate([np.zeros(6), s["hand_qdot"]]), effort=np.zeros(0)))
            if rendered:
                _add_rendered(ts, add, t, s, intrinsics, spec, (index, k) in hidden)
            else:
                rot_tool = Rotation.from_quat(s["tool_quat"], scalar_first=True).as_matrix()
                tool_hand = synth.from_tool_pose(rot_tool, s["tool_pos"], s["hinge"]).astype(float)
                world = tool_hand @ s["hand_rot"].T + s["hand_pos"]
                add(t + 30_000_000, "/camera/depth/points",
                    point_cloud2(ts, t, CAMERA_OPTICAL, (world - cam_pos) @ cam_rot))
            if spec.object_pose:
                p = s["object"]
                add(t + 30_000_000, "/object/pose", T["geometry_msgs/msg/PoseStamped"](
                    header=_header(ts, t, "world"), pose=T["geometry_msgs/msg/Pose"](
                        position=T["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
                        orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))))
            if k < len(trial["actions"]):
                add(t, "/hingelab/action", T["std_msgs/msg/Float64MultiArray"](
                    layout=T["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0), data=trial["actions"][k]))
        hit = np.flatnonzero(trial["is_success"])
        events = [(stamps[0], "start")]
        if trial["success"]:
            events.append((stamps[hit[0] + 1], "success"))
        else:
            events.append((stamps[-1], f"failure:{trial['failure_reason'] or 'timeout'}"))
        events.append((stamps[-1], "end"))
        for t, text in events:
            add(t, "/trial/event", T["std_msgs/msg/String"](data=text))
        start_s += (len(stamps) - 1) * STEP_S + spec.gap_s
    messages.sort(key=lambda m: (m[0], m[1]))
    connections = {}
    with Writer(Path(path), version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for log_ns, _, topic, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=ts)
            writer.write(connections[topic], log_ns, ts.serialize_cdr(msg, msg.__msgtype__))
    return {"trials": trials, "messages": len(messages)}


def _add_rendered(ts, add, t: int, state: dict, intrinsics, spec: SimRigBagSpec, hidden: bool) -> None:
    """One rendered frame: the depth image and its camera_info (and the object's mask), or the scene cloud."""
    depth, mask = state["depth"], state["object_mask"]
    if hidden:  # the object's pixels give no return: nothing of it is seen
        depth, mask = np.where(mask, np.float32(0.0), depth), np.zeros_like(mask)
    k = intrinsics
    if spec.camera == "points":
        add(t + 30_000_000, KINDS["points"].default,
            point_cloud2(ts, t, CAMERA_OPTICAL, depth_to_points(depth, k).astype(np.float32)))
        return
    add(t + 30_000_000, KINDS["camera_info"].default,
        camera_info_message(ts, t, CAMERA_OPTICAL, k.width, k.height, k.fx, k.fy, k.cx, k.cy))
    add(t + 30_000_000, KINDS["depth"].default, image_message(ts, t, CAMERA_OPTICAL, depth))
    if spec.object_mask:
        add(t + 40_000_000, KINDS["object_mask"].default,
            image_message(ts, t, CAMERA_OPTICAL, mask.astype(np.uint8) * np.uint8(255)))


__all__ = ["SimRigBagSpec", "write_sim_rig_bag"]

"""ROS 2 export and import as a user runs them, with no --topic flag: a rig bag imported, exported and imported again
gives the same episodes field by field (seeds included); a stand-in trial's export keeps its depth images, camera
info and the camera's fixed mount on /tf_static; the standard-typed topics of an export hold no NaN."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from hingelab.cli.main import main
from hingelab.episodes import read_episode
from hingelab.episodes.camera_topics import read_camera
from hingelab.episodes.dataset import Dataset
from hingelab.ros2 import ros_messages as M
from hingelab.ros2.rig_bag import RigBagSpec, RigTrial, write_rig_bag
from hingelab.ros2.tf_tree import TfTree

KEPT_METADATA = ("seed", "object", "length", "success", "attempt", "first_attempt_success", "failure_reason",
                 "ros2_trial_start_ns", "ros2_trial_end_ns", "action_level", "source", "task")


def _episodes(root: Path) -> list:
    return sorted((read_episode(p) for p in Dataset(root).paths()), key=lambda e: e.metadata["seed"])


def _bag(path: Path) -> dict:
    """{topic: (msgtype, [(log time, message)])} read with rosbags alone."""
    topics = {}
    with AnyReader([path]) as reader:
        for connection, t, raw in reader.messages():
            entry = topics.setdefault(connection.topic, (connection.msgtype, []))
            entry[1].append((t, reader.deserialize(raw, connection.msgtype)))
    return topics


def _numbers(msg, where: str) -> list[np.ndarray]:
    """Every float of a standard message (a PointCloud2's points decoded), recursively."""
    if msg.__msgtype__ == "sensor_msgs/msg/PointCloud2":
        data = np.asarray(msg.data, np.uint8).view("<f4")
        return [data]
    out = []
    for name in msg.__dataclass_fields__:
        value = getattr(msg, name)
        if hasattr(value, "__msgtype__"):
            out += _numbers(value, where)
        elif isinstance(value, list) and value and hasattr(value[0], "__msgtype__"):
            for item in value:
                out += _numbers(item, where)
        elif isinstance(value, (float, np.ndarray)) and np.asarray(value).dtype.kind == "f":
            out.append(np.asarray(value))
    return out


def assert_standard_topics_finite(bag: dict) -> None:
    for topic, (msgtype, rows) in bag.items():
        if msgtype.startswith("hingelab_msgs/"):
            continue  # the episode's own values, NaN included where it records none (a real trial's reward)
        for t, msg in rows:
            for values in _numbers(msg, topic):
                assert np.isfinite(values).all(), (topic, t)


@pytest.fixture(scope="module")
def rig_round_trip(tmp_path_factory):
    """A rig bag (a first-attempt success, a failure after two attempts) imported, exported, imported again."""
    root = tmp_path_factory.mktemp("round")
    write_rig_bag(root / "rig_bag", RigBagSpec(trials=[RigTrial(duration_s=0.6),
                                                       RigTrial(duration_s=0.6, outcome="failure", attempts=2)],
                                               gap_s=0.3))
    assert main(["datasets", "import-ros2", str(root / "rig_bag"), "--out", str(root / "real"), "--no-progress"]) == 0
    assert main(["datasets", "export", str(root / "real"), "--format", "ros2", "--out", str(root / "bags")]) == 0
    bags = sorted((root / "bags").iterdir())
    assert main(["datasets", "import-ros2", *map(str, bags), "--out", str(root / "back"), "--no-progress"]) == 0
    return root, bags


def test_import_export_import_gives_the_same_episodes_field_by_field(rig_round_trip):
    root, bags = rig_round_trip
    originals, again = _episodes(root / "real"), _episodes(root / "back")
    assert [e.metadata["seed"] for e in originals] == [0, 1]  # the trial's index in the rig bag
    assert len(again) == len(originals) == len(bags) == 2
    for original, copy in zip(originals, again):
        for key in KEPT_METADATA:
            assert copy.metadata.get(key) == original.metadata.get(key), key
        assert copy.metadata["ros2_exported_episode_id"] == original.metadata["episode_id"]
        assert set(copy.topics) == set(original.topics)
        for topic, fields in original.topics.items():
            assert set(copy.topics[topic]) == set(fields), topic
            for name, value in fields.items():
                if name.startswith("info.age_"):
                    continue  # how old each sample was on the rig; the export stamps every sample at its step
                np.testing.assert_array_equal(copy.topics[topic][name], value, err_msg=f"{topic} {name}")
        np.testing.assert_array_equal(copy.points, original.points)  # taken as exported, not re-sampled


def test_the_export_labels_actions_and_keeps_the_episode_and_every_topic(rig_round_trip):
    root, bags = rig_round_trip
    original = _episodes(root / "real")[0]
    bag = _bag(root / "bags" / original.metadata["episode_id"])  # its own bag: the ids' order is not the seeds'
    for topic in ("/joint_states", "/tool/points", "/tf", "/trial/event", "/hingelab/action", "/object/pose",
                  "/hingelab/episode", "/hingelab/step", "/hingelab/tool/latent"):
        assert topic in bag, topic
    assert bag["/hingelab/tool/latent"][0] == "hingelab_msgs/msg/ToolLatent"
    (dim,) = bag["/hingelab/action"][1][0][1].layout.dim
    assert dim.label == "z_goal_0,z_goal_1,hand_velocity_x,hand_velocity_y,hand_velocity_z" and dim.size == 5
    latent = np.stack([m.z_smoothed for _, m in bag["/hingelab/tool/latent"][1]])
    np.testing.assert_array_equal(latent, original.topics["/tool/latent"]["z_smoothed"])
    steps = [m for _, m in bag["/hingelab/step"][1]]
    np.testing.assert_array_equal([m.info_attempt for m in steps], original.topics["/step"]["info.attempt"])
    frames = {tr.header.frame_id + ">" + tr.child_frame_id for _, m in bag["/tf"][1] for tr in m.transforms}
    assert frames == {"world>hand_base", "hand_base>tool"}  # the arm's kinematics from the recorded arm joints
    assert_standard_topics_finite(bag)


@pytest.fixture(scope="module")
def stand_in_export(tmp_path_factory):
    """``hingelab trial --robot sim`` (one short trial) exported as ROS 2 bags."""
    root = tmp_path_factory.mktemp("stand_in")
    assert main(["trial", "--robot", "sim", "--trials", "1", "--max-steps", "8", "--depth-every", "4",
                 "--out", str(root / "trial"), "--no-progress"]) == 0
    assert main(["datasets", "export", str(root / "trial"), "--format", "ros2", "--out", str(root / "bags")]) == 0
    (bag,) = (root / "bags").iterdir()
    (path,) = Dataset(root / "trial").paths()
    return root, path, bag


def test_a_stand_in_trial_keeps_its_depth_images_camera_info_and_camera_mount(stand_in_export):
    root, path, bag_path = stand_in_export
    camera = read_camera(path)
    bag = _bag(bag_path)
    assert bag["/camera/depth/image_raw"][0] == "sensor_msgs/msg/Image"
    images = [m for _, m in bag["/camera/depth/image_raw"][1]]
    infos = [m for _, m in bag["/camera/depth/camera_info"][1]]
    assert len(images) == len(infos) == len(camera.log_time_ns) == 2  # steps 0 and 4
    for image, info, depth in zip(images, infos, camera.depth):
        assert image.encoding == "16UC1" and image.header.frame_id == "camera_depth_optical"
        np.testing.assert_array_equal(M.depth_image_m(image, "test"), depth)
        k = M.intrinsics_from_camera_info(info)
        assert (k.width, k.height, k.fx, k.fy, k.cx, k.cy) == (
            camera.intrinsics.width, camera.intrinsics.height, camera.intrinsics.fx, camera.intrinsics.fy,
            camera.intrinsics.cx, camera.intrinsics.cy)
    (static,) = [m for _, m in bag["/tf_static"][1]]
    assert [(tr.header.frame_id, tr.child_frame_id) for tr in static.transforms] == [("world", "camera_depth_optical")]
    tree = TfTree()
    tree.add(static, True)
    for _, msg in bag["/tf"][1]:
        tree.add(msg, False)
    tree.finish()
    origin = int(read_episode(path).metadata["log_time_origin_ns"])  # the bag is stamped at the wall-clock start
    assert origin > 10**18  # after 2001, not 1970
    for j, t in enumerate(camera.log_time_ns):  # the camera in the hand through the tree, as recorded
        rot, pos, _ = tree.lookup("hand_base", "camera_depth_optical", origin + int(t))
        np.testing.assert_allclose(pos, camera.position[j], atol=1e-4)
        np.testing.assert_allclose(rot, camera.rotation[j], atol=1e-4)
    assert {"/arm/joints"} <= set(read_episode(path).topics)
    (joints,) = {len(m.name) for _, m in bag["/joint_states"][1]}
    assert joints == 15  # the hand's 9 channels and the arm's 6 joints in one message
    assert_standard_topics_finite(bag)


def test_a_stand_in_export_imports_back_without_flags_with_its_seed(stand_in_export):
    root, path, bag_path = stand_in_export
    assert main(["datasets", "import-ros2", str(bag_path), "--out", str(root / "back"), "--no-progress"]) == 0
    original = read_episode(path)
    (copy,) = _episodes(root / "back")
    assert copy.metadata["seed"] == original.metadata["seed"] != 0
    assert copy.metadata["object"] == original.metadata["object"] == "sphere"
    assert copy.metadata["success"] == original.metadata["success"]
    for topic, name in (("/hand/joints", "position"), ("/action", "values"), ("/object/position", "position"),
                        ("/tool/pose", "position"), ("/tool/latent", "z_smoothed")):
        np.testing.assert_array_equal(copy.topics[topic][name], original.topics[topic][name], err_msg=topic)
    np.testing.assert_array_equal(copy.points, original.points)
    # the depth images and camera info are a camera the import reads too: tool clouds from them alone
    assert main(["datasets", "import-ros2", str(bag_path), "--topic", "tool_points=/not/there", "--out",
                 str(root / "from_depth"), "--no-progress"]) == 0
    (from_depth,) = _episodes(root / "from_depth")
    assert from_depth.metadata["ros2_topics_used"].count("depth=/camera/depth/image_raw") == 1
    assert np.isfinite(from_depth.points).all() and len(from_depth.points) >= 1

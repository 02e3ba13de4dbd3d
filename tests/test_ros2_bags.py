"""ROS 2 bags in and out: bags written here with the ``rosbags`` writer at the rig's rates (30 Hz
camera, 100 Hz joints and TF, static TF, trials with events) imported as episodes, checked against
the bag read independently with ``rosbags``; the export read back; every bad input a one-line error
or a reported case."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from hingelab.cli.main import main
from hingelab.episodes import read_episode
from hingelab.episodes.dataset import Dataset
from hingelab.perception.camera_cloud import ToolCloudConfig
from hingelab.ros2.rig_bag import RigBagSpec, RigTrial, write_rig_bag

STEP_NS = 50_000_000


def _episodes(root: Path) -> list:
    """The dataset's episodes in trial order."""
    episodes = [read_episode(p) for p in Dataset(root).paths()]
    return sorted(episodes, key=lambda e: (e.metadata["ros2_bag"], int(e.metadata["ros2_trial_start_ns"])))


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) >= 1 and err[-1].startswith("hingelab: error: ") and "Traceback" not in "\n".join(err)
    return err[-1]


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    """The default rig bag (three trials: a first-attempt success, a failure, a second-attempt success), imported."""
    root = tmp_path_factory.mktemp("rig")
    info = write_rig_bag(root / "rig_bag")
    assert main(["datasets", "import-ros2", str(root / "rig_bag"), "--out", str(root / "real"), "--no-progress"]) == 0
    return root, info


def _bag_messages(path: Path, topic: str):
    """(header stamps or log times, decoded messages) of a topic, read with rosbags alone, in stamp order."""
    with AnyReader([path]) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        rows = []
        for c, t, raw in reader.messages(connections=connections):
            msg = reader.deserialize(raw, c.msgtype)
            header = getattr(msg, "header", None)
            rows.append((header.stamp.sec * 10**9 + header.stamp.nanosec if header else t, msg))
    rows.sort(key=lambda r: r[0])
    return np.array([r[0] for r in rows], np.int64), [r[1] for r in rows]


def test_each_trial_is_an_episode_with_its_outcome_and_the_bags_facts(rig):
    root, info = rig
    episodes = _episodes(root / "real")
    assert len(episodes) == 3
    for episode, trial in zip(episodes, info["trials"]):
        meta = episode.metadata
        expected = (trial["end_ns"] - trial["start_ns"]) // STEP_NS + 1  # 20 Hz from start, up to end
        assert meta["length"] == expected == 25 and len(episode.topics["/step"]["reward"]) == expected
        assert np.array_equal(episode.topics["/step"]["log_time_ns"], np.arange(expected) * STEP_NS)
        assert meta["source"] == "real" and meta["ros2_bag"] == "rig_bag"
        assert (int(meta["ros2_trial_start_ns"]) == trial["start_ns"]
                and int(meta["ros2_trial_end_ns"]) == trial["end_ns"])
        assert meta["log_time_origin_ns"] == trial["start_ns"]  # logged at the rig's clock, read from 0
        assert meta["ros2_bag_topics"].split(",") == sorted(info["names"][k] for k in (
            "joints", "points", "tf", "tf_static", "events", "action", "object"))
        assert int(meta["ros2_bag_start_ns"]) <= trial["start_ns"] < trial["end_ns"] <= int(meta["ros2_bag_end_ns"])
        assert episode.points.shape == (expected, 256, 3)
        low, high = np.array(ToolCloudConfig().crop_low), np.array(ToolCloudConfig().crop_high)
        assert (episode.points >= low).all() and (episode.points <= high).all()  # the tool, in hand_base
        assert np.isfinite(episode.topics["/tool/latent"]["z_smoothed"]).all()
        assert episode.topics["/hand/joints"]["position"].shape == (expected, 9)
    first, failed, second = (e.metadata for e in episodes)
    assert first["success"] is True and first["attempt"] == 1 and first["first_attempt_success"] is True
    assert failed["success"] is False and failed["failure_reason"] == "slip" and failed["attempt"] == 1
    assert second["success"] is True and second["attempt"] == 2 and second["first_attempt_success"] is False
    assert "failure_reason" not in second
    step = episodes[2].topics["/step"]
    assert step["info.attempt"][0] == 1 and step["info.attempt"][-1] == 2  # the attempt event mid-trial
    assert step["info.is_success"][0] == 0 and step["info.is_success"][-1] == 1
    assert step["terminated"][-1] and not step["terminated"][:-1].any() and not step["truncated"].any()


def test_no_step_holds_a_message_stamped_after_it(rig):
    """Every stream at the latest message stamped at or before the step, checked against the bag itself."""
    root, _ = rig
    bag = root / "rig_bag"
    joint_stamps, joint_msgs = _bag_messages(bag, "/joint_states")
    action_stamps, action_msgs = _bag_messages(bag, "/hingelab/action")
    cloud_stamps, _ = _bag_messages(bag, "/camera/depth/points")
    for episode in _episodes(root / "real"):
        step = episode.topics["/step"]
        times = int(episode.metadata["ros2_trial_start_ns"]) + step["log_time_ns"]
        for k, t in enumerate(times):
            j = np.searchsorted(joint_stamps, t, side="right") - 1
            assert joint_stamps[j] <= t
            assert np.array_equal(episode.topics["/hand/joints"]["position"][k], joint_msgs[j].position[6:])
            assert step["info.arm_joint_1"][k] == joint_msgs[j].position[0]
            assert step["info.age_joints_s"][k] == pytest.approx((t - joint_stamps[j]) / 1e9, abs=1e-9)
            a = np.searchsorted(action_stamps, t, side="right") - 1
            assert np.array_equal(episode.topics["/action"]["values"][k], action_msgs[a].data)
            c = np.searchsorted(cloud_stamps, t, side="right") - 1
            assert step["info.age_cloud_s"][k] == pytest.approx((t - cloud_stamps[c]) / 1e9, abs=1e-9)
        for name in ("joints", "arm_joints", "cloud", "tf", "action", "object"):
            ages = step[f"info.age_{name}_s"]
            assert (ages >= 0).all(), name  # never a later message
        assert step["info.age_joints_s"].max() < 0.011 and step["info.age_cloud_s"].max() < 1 / 30 + 1e-6
        assert np.array_equal(step["info.age_arm_joints_s"], step["info.age_joints_s"])  # one driver: one message
        # actions are logged 1 ms after each 20 Hz tick: a step never takes the one about to come
        assert step["info.age_action_s"].min() == pytest.approx(0.049)


def test_exported_episodes_are_ros2_bags_that_import_back_to_the_same_steps(rig, capsys):
    root, _ = rig
    out = root / "exported"
    assert main(["datasets", "export", str(root / "real"), "--format", "ros2", "--out", str(out)]) == 0
    assert "Exported 3 episodes (75 steps)" in capsys.readouterr().out
    bags = sorted(out.iterdir())
    assert len(bags) == 3 and all((b / "metadata.yaml").exists() and list(b.glob("*.mcap")) for b in bags)
    with AnyReader([bags[0]]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert types == {"/joint_states": "sensor_msgs/msg/JointState", "/tool/points": "sensor_msgs/msg/PointCloud2",
                     "/tf": "tf2_msgs/msg/TFMessage", "/trial/event": "std_msgs/msg/String",
                     "/hingelab/action": "std_msgs/msg/Float64MultiArray",
                     "/object/pose": "geometry_msgs/msg/PoseStamped", "/hingelab/episode": "std_msgs/msg/String",
                     "/hingelab/step": "hingelab_msgs/msg/Step",
                     "/hingelab/tool/latent": "hingelab_msgs/msg/ToolLatent"}
    assert counts["/tool/points"] == 25 and counts["/joint_states"] == 50  # the hand's and the arm's messages
    back = root / "back"
    assert main(["datasets", "import-ros2", *map(str, bags), "--topic", "points=/tool/points", "--out", str(back),
                 "--no-progress"]) == 0
    originals = {e.metadata["ros2_trial_start_ns"]: e for e in _episodes(root / "real")}
    again = _episodes(back)
    assert len(again) == 3
    for episode in again:
        original = originals[episode.metadata["ros2_trial_start_ns"]]
        for key in ("length", "success", "attempt", "first_attempt_success", "ros2_trial_end_ns"):
            assert episode.metadata[key] == original.metadata[key], key
        assert episode.metadata.get("failure_reason") == original.metadata.get("failure_reason")
        for topic, field in (("/step", "log_time_ns"), ("/hand/joints", "position"), ("/hand/joints", "velocity"),
                             ("/action", "values"), ("/object/position", "position"), ("/step", "info.is_success"),
                             ("/step", "info.attempt"), ("/step", "info.arm_joint_3"), ("/step", "terminated")):
            assert np.array_equal(episode.topics[topic][field], original.topics[topic][field]), (topic, field)
        assert (episode.topics["/step"]["info.age_joints_s"] == 0).all()  # stamped at its step
        # the cloud goes through the pipeline again (2 mm voxels of a 2 mm cloud): the same surface
        for a, b in zip(episode.points, original.points):
            gaps = np.linalg.norm(a[:, None] - b[None], axis=2).min(axis=1)
            assert np.median(gaps) < 0.001 and gaps.max() < 0.004


def test_sqlite3_storage_depth_images_and_a_standalone_mcap(tmp_path, capsys):
    spec = RigBagSpec(trials=[RigTrial(duration_s=0.5)], gap_s=0.2, storage="sqlite3", depth_images=True,
                      action=False, object_pose=False)
    write_rig_bag(tmp_path / "sqlite_bag", spec)
    assert list((tmp_path / "sqlite_bag").glob("*.db3"))
    assert main(["datasets", "import-ros2", str(tmp_path / "sqlite_bag"), "--out", str(tmp_path / "a"),
                 "--no-progress"]) == 0
    (episode,) = _episodes(tmp_path / "a")
    assert episode.metadata["length"] == 11 and episode.points.shape == (11, 256, 3)
    assert "/action" not in episode.topics and np.isnan(episode.topics["/step"]["info.age_action_s"]).all()
    write_rig_bag(tmp_path / "mcap_bag", RigBagSpec(trials=[RigTrial(duration_s=0.5)], gap_s=0.2))
    (standalone,) = (tmp_path / "mcap_bag").glob("*.mcap")
    assert main(["datasets", "import-ros2", str(standalone), "--out", str(tmp_path / "b"), "--no-progress"]) == 0
    assert "1 episodes, 11 steps" in capsys.readouterr().out
    assert _episodes(tmp_path / "b")[0].metadata["ros2_bag"] == standalone.name


def test_a_missing_topic_names_it_and_the_flag(tmp_path, capsys):
    write_rig_bag(tmp_path / "bag", RigBagSpec(trials=[RigTrial(duration_s=0.3)], gap_s=0.2,
                                               topics={"joints": "/svh/joint_states", "points": "/k4a/points2"}))
    assert main(["datasets", "import-ros2", str(tmp_path / "bag"), "--out", str(tmp_path / "a")]) == 1
    line = _one_line_error(capsys)
    assert "no topic /joint_states" in line and "--topic joints=NAME" in line and "/svh/joint_states" in line
    assert main(["datasets", "import-ros2", str(tmp_path / "bag"), "--out", str(tmp_path / "a"),
                 "--topic", "joints=/svh/joint_states"]) == 1
    line = _one_line_error(capsys)
    assert "no topic /camera/depth/points" in line and "--topic points=NAME" in line
    assert main(["datasets", "import-ros2", str(tmp_path / "bag"), "--out", str(tmp_path / "b"), "--no-progress",
                 "--topic", "joints=/svh/joint_states", "--topic", "points=/k4a/points2"]) == 0
    assert "1 episodes, 7 steps" in capsys.readouterr().out
    assert main(["datasets", "import-ros2", str(tmp_path / "bag"), "--out", str(tmp_path / "c"),
                 "--topic", "cloud"]) == 1
    assert "KIND=NAME" in _one_line_error(capsys)
    assert main(["datasets", "import-ros2", str(tmp_path / "nowhere"), "--out", str(tmp_path / "d")]) == 1
    assert "nowhere does not exist" in _one_line_error(capsys)


def test_a_topic_of_another_type_names_both_types(tmp_path, capsys):
    ts = get_typestore(Stores.ROS2_HUMBLE)
    String = ts.types["std_msgs/msg/String"]
    with Writer(tmp_path / "bag", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        joints = writer.add_connection("/joint_states", String.__msgtype__, typestore=ts)
        events = writer.add_connection("/trial/event", String.__msgtype__, typestore=ts)
        writer.write(joints, 10**9, ts.serialize_cdr(String(data="q"), String.__msgtype__))
        writer.write(events, 10**9, ts.serialize_cdr(String(data="start"), String.__msgtype__))
    assert main(["datasets", "import-ros2", str(tmp_path / "bag"), "--out", str(tmp_path / "a")]) == 1
    line = _one_line_error(capsys)
    assert "/joint_states is std_msgs/msg/String" in line and "sensor_msgs/msg/JointState" in line


def test_non_monotonic_stamps_are_reported_and_reordered(tmp_path, capsys):
    write_rig_bag(tmp_path / "bag", RigBagSpec(trials=[RigTrial(duration_s=0.6)], gap_s=0.2, non_monotonic_joints=6))
    assert main(["datasets", "import-ros2", str(tmp_path / "bag"), "--out", str(tmp_path / "a"), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "6 messages on /joint_states were stamped earlier than the one before them (non-monotonic stamps)" in out
    (episode,) = _episodes(tmp_path / "a")
    assert episode.metadata["length"] == 13
    stamps, msgs = _bag_messages(tmp_path / "bag", "/joint_states")  # sorted by stamp
    step = episode.topics["/step"]
    times = int(episode.metadata["ros2_trial_start_ns"]) + step["log_time_ns"]
    for k, t in enumerate(times):
        j = np.searchsorted(stamps, t, side="right") - 1
        assert np.array_equal(episode.topics["/hand/joints"]["position"][k], msgs[j].position[6:])
    assert (step["info.age_joints_s"] >= 0).all()


def test_a_bag_cut_off_mid_chunk_imports_what_is_whole(tmp_path, capsys):
    from mcap.reader import make_reader

    info = write_rig_bag(tmp_path / "bag", RigBagSpec(trials=[RigTrial(duration_s=0.6)] * 4, gap_s=0.3))
    (mcap_file,) = (tmp_path / "bag").glob("*.mcap")
    with open(mcap_file, "rb") as f:
        chunks = sorted(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert len(chunks) >= 2
    cut = tmp_path / "cut"
    shutil.copytree(tmp_path / "bag", cut)
    with open(cut / mcap_file.name, "r+b") as f:
        f.truncate(chunks[1].chunk_start_offset + chunks[1].chunk_length // 2)  # inside the second chunk
    assert main(["datasets", "import-ros2", str(cut), "--out", str(tmp_path / "a"), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "is cut off" in out and "messages read; metadata.yaml lists" in out
    episodes = _episodes(tmp_path / "a")
    whole = [t for t in info["trials"] if t["end_ns"] <= chunks[0].message_end_time]
    assert whole and len(episodes) < len(info["trials"])
    imported = {int(e.metadata["ros2_trial_start_ns"]): e for e in episodes}
    for trial in whole:  # every trial inside the complete chunk is imported whole
        episode = imported[trial["start_ns"]]
        assert episode.metadata["ros2_trial_closed_by"] == "end"
        assert episode.metadata["length"] == (trial["end_ns"] - trial["start_ns"]) // STEP_NS + 1
    last = max(imported.values(), key=lambda e: int(e.metadata["ros2_trial_start_ns"]))
    # the trial the cut went through
    if int(last.metadata["ros2_trial_start_ns"]) not in {t["start_ns"] for t in whole}:
        assert last.metadata["ros2_trial_closed_by"] == "last_message" and "no end event" in out
    # the same whole trials from the intact bag: identical steps
    assert main(["datasets", "import-ros2", str(tmp_path / "bag"), "--out", str(tmp_path / "b"), "--no-progress"]) == 0
    intact = {int(e.metadata["ros2_trial_start_ns"]): e for e in _episodes(tmp_path / "b")}
    for trial in whole:
        a, b = imported[trial["start_ns"]], intact[trial["start_ns"]]
        assert np.array_equal(a.topics["/hand/joints"]["position"], b.topics["/hand/joints"]["position"])
        assert np.array_equal(a.points, b.points)


def test_a_trial_without_end_closes_at_the_last_message_and_says_so(tmp_path, capsys):
    write_rig_bag(tmp_path / "bag", RigBagSpec(trials=[RigTrial(duration_s=0.4),
                                                       RigTrial(duration_s=0.4, end_event=False)],
                                               gap_s=0.2))
    assert main(["datasets", "import-ros2", str(tmp_path / "bag"), "--out", str(tmp_path / "a"), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "has no end event; closed at the bag's last message" in out
    first, second = _episodes(tmp_path / "a")
    assert first.metadata["ros2_trial_closed_by"] == "end"
    assert second.metadata["ros2_trial_closed_by"] == "last_message"
    assert second.metadata["success"] is True  # its success event came before the bag ended
    assert second.topics["/step"]["truncated"][-1] and not second.topics["/step"]["terminated"].any()
    assert second.metadata["length"] > first.metadata["length"]  # it ran on to the bag's last message (the gap)


def test_frames_without_a_tool_cloud_are_dropped_and_the_steps_take_an_earlier_one(tmp_path, capsys):
    blind = tuple(range(10, 24))  # 14 frames (0.47 s at 30 Hz) that see only the table, inside the trial
    write_rig_bag(tmp_path / "bag", RigBagSpec(trials=[RigTrial(duration_s=1.0)], gap_s=0.2, blind_frames=blind))
    assert main(["datasets", "import-ros2", str(tmp_path / "bag"), "--out", str(tmp_path / "a"), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "camera frames without a tool cloud in the crop box (too_few_points)" in out
    (episode,) = _episodes(tmp_path / "a")
    step = episode.topics["/step"]
    times = int(episode.metadata["ros2_trial_start_ns"]) + step["log_time_ns"]
    stamps, _ = _bag_messages(tmp_path / "bag", "/camera/depth/points")
    last_seen = stamps[blind[0] - 1]  # the last frame with the tool before the blind run
    held = (times >= stamps[blind[0]]) & (times < stamps[blind[-1] + 1])
    assert held.sum() >= 8
    # those steps hold the last frame that saw the tool: older than one frame period, never a later one
    assert step["info.age_cloud_s"][held] == pytest.approx((times[held] - last_seen) / 1e9, abs=1e-9)
    assert (step["info.age_cloud_s"] >= 0).all() and step["info.age_cloud_s"][~held].max() < 1 / 30 + 1e-6


def test_arm_and_hand_from_their_own_drivers_on_one_topic(tmp_path, capsys):
    """The arm's and the hand's drivers both publish on /joint_states: each part from its own messages."""
    write_rig_bag(tmp_path / "bag", RigBagSpec(trials=[RigTrial(duration_s=0.5)], gap_s=0.2, split_joint_drivers=True))
    assert main(["datasets", "import-ros2", str(tmp_path / "bag"), "--out", str(tmp_path / "a"), "--no-progress"]) == 0
    (episode,) = _episodes(tmp_path / "a")
    stamps, msgs = _bag_messages(tmp_path / "bag", "/joint_states")
    hand = np.array([len(m.name) == 9 for m in msgs])
    step = episode.topics["/step"]
    times = int(episode.metadata["ros2_trial_start_ns"]) + step["log_time_ns"]
    for k, t in enumerate(times):
        h = np.flatnonzero(hand & (stamps <= t))[-1]
        a = np.flatnonzero(~hand & (stamps <= t))[-1]
        assert np.array_equal(episode.topics["/hand/joints"]["position"][k], msgs[h].position)
        assert step["info.arm_joint_6"][k] == msgs[a].position[5]
        assert step["info.age_joints_s"][k] == pytest.approx((t - stamps[h]) / 1e9, abs=1e-9)
        assert step["info.age_arm_joints_s"][k] == pytest.approx((t - stamps[a]) / 1e9, abs=1e-9)
    # a hand driver with other names: one line naming the channels it lacks
    write_rig_bag(tmp_path / "other", RigBagSpec(trials=[RigTrial(duration_s=0.3)], gap_s=0.2,
                                                 hand_joint_names=tuple(f"j{i}" for i in range(9))))
    assert main(["datasets", "import-ros2", str(tmp_path / "other"), "--out", str(tmp_path / "b")]) == 1
    line = _one_line_error(capsys)
    assert ("/joint_states has no message with the hand's joint(s) svh_thumb_flexion" in line
            and "HAND_ACTUATORS" in line)


def test_a_simulated_episode_exports_as_a_ros2_bag_and_imports_back(random_pick_dataset, tmp_path, capsys):
    """A ToolPick-v0 recording (RecordingWrapper: a reset record, then one record per step) as a bag."""
    root = random_pick_dataset("sim_to_ros2", episodes=1, max_episode_steps=5)
    (original,) = [read_episode(p) for p in Dataset(root).paths()]
    assert main(["datasets", "export", str(root), "--format", "ros2", "--out", str(tmp_path / "bags")]) == 0
    (bag,) = (tmp_path / "bags").iterdir()
    with AnyReader([bag]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        events = [reader.deserialize(raw, c.msgtype).data for c, _, raw in reader.messages(
            connections=[c for c in reader.connections if c.topic == "/trial/event"])]
        start_ns = reader.start_time
    # stamped from the episode's wall-clock start (schema 6), so a bag viewer does not date it 1970
    assert start_ns == int(original.metadata["log_time_origin_ns"]) > 10**18
    assert counts["/tool/points"] == len(original.points) and counts["/joint_states"] == len(
        original.topics["/hand/joints"]["log_time_ns"])
    assert events[0] == "start" and events[-1] == "end"
    assert ("success" in events) == original.metadata["success"]
    assert main(["datasets", "import-ros2", str(bag), "--topic", "points=/tool/points", "--out", str(tmp_path / "back"),
                 "--no-progress"]) == 0
    (again,) = _episodes(tmp_path / "back")
    steps = original.topics["/step"]["log_time_ns"]
    assert again.metadata["length"] == len(steps) and again.metadata["success"] == original.metadata["success"]
    joints = original.topics["/hand/joints"]
    rows = np.searchsorted(joints["log_time_ns"], steps)  # the joint state logged with each step
    assert np.array_equal(again.topics["/hand/joints"]["position"], joints["position"][rows])
    assert np.array_equal(again.topics["/action"]["values"], original.topics["/action"]["values"][
        np.searchsorted(original.topics["/action"]["log_time_ns"], steps)])


def test_real_size_clouds_are_cropped_before_the_transform_and_read_as_before():
    """A real camera's whole-scene cloud: dropping the points outside the crop box's sphere in the camera frame
    keeps exactly the points the pipeline's crop in hand_base keeps; the float32 view of the bytes reads the
    same points as the general (structured) decoding, padded points (x y z + rgb, 16 bytes) too."""
    from hingelab.perception.camera_cloud import crop, transform
    from hingelab.ros2 import ros_messages as M
    from hingelab.ros2.bag_import import near_crop_box
    from hingelab.ros2.rig_bag import camera_in_hand

    config = ToolCloudConfig()
    rot, pos = camera_in_hand(0.3)
    rng = np.random.default_rng(0)
    inside_hand = rng.uniform(config.crop_low, config.crop_high, (5_000, 3))  # the box, and the scene around it
    scene_cam = np.concatenate([(inside_hand - pos) @ rot, rng.uniform(-1.5, 1.5, (200_000, 3))])
    kept = near_crop_box(scene_cam, rot, pos, config)
    assert len(kept) < 0.1 * len(scene_cam)
    expected = crop(transform(scene_cam, rot, pos), config.crop_low, config.crop_high)
    got = crop(transform(kept, rot, pos), config.crop_low, config.crop_high)
    assert len(got) == len(expected) >= 5_000
    np.testing.assert_allclose(got, expected, atol=1e-12)
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    xyz = rng.normal(size=(1000, 3)).astype("<f4")
    xyz[7, 1] = np.nan
    padded = np.zeros((1000, 4), "<f4")
    padded[:, :3] = xyz
    for big_endian in (False, True):
        data = padded.astype(">f4" if big_endian else "<f4")
        fields = [T["sensor_msgs/msg/PointField"](name=n, offset=4 * i, datatype=7, count=1)
                  for i, n in enumerate("xyzr")]
        msg = T["sensor_msgs/msg/PointCloud2"](
            header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="c"),
            height=1, width=1000, fields=fields, is_bigendian=big_endian, point_step=16, row_step=16000,
            data=data.view(np.uint8).ravel(), is_dense=False)
        points = M.cloud_xyz(msg, "test")
        np.testing.assert_array_equal(points, np.delete(xyz, 7, axis=0).astype(np.float64))

"""The topics a ROS 2 bag import reads: kinds, default names, expected types, ``--topic KIND=NAME``.

Each kind has a default topic name (what the rig's drivers publish, or what ``hingelab datasets
export --format ros2`` writes: ``tool_points``, ``episode``) and one expected message type, so an
export imports back without flags. ``--topic KIND=NAME`` renames a kind's topic; a kind's type is fixed.
"""

from __future__ import annotations

from dataclasses import dataclass

from hingelab.errors import ConfigError
from hingelab.sim.names import ARM_JOINTS, HAND_ACTUATORS


@dataclass(frozen=True)
class TopicKind:
    kind: str
    default: str
    msgtype: str
    required: bool
    meaning: str


KINDS = {k.kind: k for k in (
    TopicKind("joints", "/joint_states", "sensor_msgs/msg/JointState", True,
              "arm_joint_1..6 and the hand's 9 actuated channels (rad, rad/s)"),
    TopicKind("points", "/camera/depth/points", "sensor_msgs/msg/PointCloud2", False,
              "the camera's whole-scene cloud, xyz float32, camera frame"),
    TopicKind("depth", "/camera/depth/image_raw", "sensor_msgs/msg/Image", False,
              "depth image, 32FC1 metres (16UC1 millimetres also read), with camera_info"),
    TopicKind("camera_info", "/camera/depth/camera_info", "sensor_msgs/msg/CameraInfo", False,
              "the depth image's intrinsics"),
    TopicKind("object_mask", "/camera/depth/object_mask", "sensor_msgs/msg/Image", False,
              "the rig's segmentation of the object in the depth image (mono8, nonzero: the object), stamped as "
              "its image: read by --object-from-cloud (optional)"),
    TopicKind("tf", "/tf", "tf2_msgs/msg/TFMessage", False, "dynamic transforms"),
    TopicKind("tf_static", "/tf_static", "tf2_msgs/msg/TFMessage", False, "static transforms"),
    TopicKind("events", "/trial/event", "std_msgs/msg/String", True,
              "trial events: start, attempt, success, failure[:reason], abort, end"),
    TopicKind("action", "/hingelab/action", "std_msgs/msg/Float64MultiArray", False,
              "the high-level action (optional)"),
    TopicKind("object", "/object/pose", "geometry_msgs/msg/PoseStamped", False, "the object's pose (optional)"),
    TopicKind("tool_points", "/tool/points", "sensor_msgs/msg/PointCloud2", False,
              "a hingelab export's tool cloud, hand_base: read when the bag has no points topic; a cloud of the "
              "pipeline's size (256) is taken as it is"),
    TopicKind("episode", "/hingelab/episode", "std_msgs/msg/String", False,
              "a hingelab export's episode metadata (JSON): its seed and object are kept"),
)}

# The hand's channels in the episode's /hand/joints order (schemas.SVH_JOINT_NAMES), by the
# platform's actuator names; the bare names (without "svh_") are accepted too.
HAND_JOINTS = HAND_ACTUATORS
ARM_JOINT_NAMES = ARM_JOINTS


def hand_joint_aliases() -> list[tuple[str, ...]]:
    """For each of the 9 hand channels, the JointState names that mean it."""
    from hingelab.episodes import schemas as S  # the episodes' codecs (scipy): not for `hingelab --help`

    assert len(HAND_JOINTS) == len(S.SVH_JOINT_NAMES)
    return [(platform, bare) for platform, bare in zip(HAND_JOINTS, S.SVH_JOINT_NAMES)]


def topic_names(overrides=()) -> dict[str, str]:
    """{kind: topic name}: the defaults, with ``KIND=NAME`` overrides (``--topic``) applied."""
    names = {kind: k.default for kind, k in KINDS.items()}
    for text in overrides:
        kind, sep, name = str(text).partition("=")
        kind, name = kind.strip(), name.strip()
        if not sep or not name:
            raise ConfigError(f"--topic {text!r}: write KIND=NAME, e.g. --topic points=/k4a/points2")
        if kind not in KINDS:
            raise ConfigError(f"--topic {text!r}: unknown kind {kind!r}; kinds: {', '.join(KINDS)}")
        names[kind] = name if name.startswith("/") else "/" + name
    return names


__all__ = ["KINDS", "TopicKind", "HAND_JOINTS", "ARM_JOINT_NAMES", "hand_joint_aliases", "topic_names"]

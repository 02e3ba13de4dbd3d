"""The episode contract in one place: topics, message types, metadata keys, units.

Everything a reader outside hingelab needs to know is mirrored in
``datasets/README.md``; a change here is a schema-version bump (see
``SCHEMA_VERSION`` and ``reader.SUPPORTED_SCHEMA_VERSIONS``).

hingelab's own messages are protobuf types built at import time from a
``FileDescriptorProto`` (no generated ``_pb2`` file, no protoc): the file
``hingelab/episodes_v1.proto`` in package ``hingelab``. Every MCAP file carries
the full descriptor set of each schema it uses, so standard tools decode it.
"""

from __future__ import annotations

from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.JointStates_pb2 import JointStates
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.Point3InFrame_pb2 import Point3InFrame
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf import descriptor_pb2, descriptor_pool, timestamp_pb2
from google.protobuf.message_factory import GetMessageClass

# Version of topics, schemas and metadata keys. Bump on any incompatible change
# and keep the reader able to read every older version.
#   1: first version.
#   2: metadata keys ``success_verdict`` and ``last_step_success``; ToolShape-v0's ``success`` is
#      the settled verdict (version 1 recorded its last step's). Messages unchanged: the proto file
#      stays ``episodes_v1.proto``, and a version-1 file reads as before (no ``success_verdict``).
#   3: optional topics of a camera and an arm (robot trials, ``hingelab trial``): /camera/depth,
#      /camera/calibration, /camera/pose, /arm/joints; metadata key ``outcome_by`` (who judged a trial:
#      ``operator`` or ``simulation``). Files of versions 1 and 2 have none of them and read as before.
#   4: optional topics of the camera's object estimate (``object_perception`` an estimator): /object/estimate
#      (hingelab.ObjectEstimate) and /object/points; metadata key ``object_perception``. Older files have none.
#   5: metadata keys ``object_noise`` and ``object_noise_model_sha256`` (the camera's error drawn from a fitted model,
#      ``object_noise="fitted:NAME"``), whose episodes also carry /object/estimate (``estimator`` "fitted:NAME",
#      no points). Older files have neither key and read as before.
#   6: log (and publish) times start at the episode's wall-clock start: log time = ``log_time_origin_ns`` (metadata,
#      ns since the Unix epoch) + episode time; readers subtract it, so arrays keep episode-relative times (older files
#      have no key: origin 0). Topic /scene (foxglove.SceneUpdate): the object, target, tips and platform for
#      Foxglove's 3-D panel, a viewer copy of /object/position, /target/position and /sim/privileged with no arrays
#      of its own. Older files have neither and read as before.
SCHEMA_VERSION = 6

# --- frames -------------------------------------------------------------------
FRAME_HAND = "hand_base"  # the SVH hand's base frame; every position below is in it
FRAME_TOOL = "tool"  # the registered tool (tweezer) frame, child of hand_base
FRAME_CAMERA = "camera_depth_optical"  # the depth camera's optical frame (x right, y down, z forward)

# --- topics (name -> what is on it) ---------------------------------------------
TOPIC_POINTS = "/tool/points"  # foxglove.PointCloud, 256 x (x, y, z) float32 metres, hand_base
TOPIC_TOOL_POSE = "/tool/pose"  # foxglove.PoseInFrame, registered tool pose, hand_base
TOPIC_TF = "/tf"  # foxglove.FrameTransform hand_base -> tool (viewer copy of /tool/pose)
TOPIC_JOINTS = "/hand/joints"  # foxglove.JointStates, 9 actuated SVH DoF: rad, rad/s
TOPIC_LATENT = "/tool/latent"  # hingelab.ToolLatent: z (2), z_smoothed (2), unitless
TOPIC_ACTION = "/action"  # hingelab.Action: the action applied at this step
TOPIC_GOAL = "/goal"  # hingelab.LatentGoal: z_goal (2), unitless
TOPIC_REWARD = "/reward/terms"  # hingelab.RewardTerms: named terms and their sum
TOPIC_OBJECT = "/object/position"  # foxglove.Point3InFrame, metres, hand_base
TOPIC_TARGET = "/target/position"  # foxglove.Point3InFrame, metres, hand_base
TOPIC_PRIVILEGED = "/sim/privileged"  # hingelab.PrivilegedState: simulator ground truth
TOPIC_STEP = "/step"  # hingelab.Step: the compact learner record
TOPIC_COLUMNS = "/episode/columns"  # hingelab.EpisodeColumns: one message per episode
# Camera and arm (schema 3; trials record them, simulated training rollouts do not). Depth frames are
# not in /episode/columns (their size); ``hingelab.episodes.camera_topics.read_camera`` reads them.
TOPIC_DEPTH = "/camera/depth"  # foxglove.RawImage "16UC1", millimetres along the optical axis, 0: no return
TOPIC_CAMERA_CALIBRATION = "/camera/calibration"  # foxglove.CameraCalibration of the depth image (undistorted)
TOPIC_CAMERA_POSE = "/camera/pose"  # foxglove.FrameTransform hand_base -> camera_depth_optical
TOPIC_ARM_JOINTS = "/arm/joints"  # foxglove.JointStates, the arm's 6 joints: rad, rad/s
CAMERA_TOPICS = (TOPIC_DEPTH, TOPIC_CAMERA_CALIBRATION, TOPIC_CAMERA_POSE)
# The camera's object estimate (schema 4; only where ``object_perception`` names an estimator)
TOPIC_OBJECT_ESTIMATE = "/object/estimate"  # hingelab.ObjectEstimate, metres, hand_base
TOPIC_OBJECT_POINTS = "/object/points"  # foxglove.PointCloud, the object's visible points (N varies), hand_base
# Foxglove's 3-D panel does not draw Point3InFrame: the scene's objects as SceneUpdate entities (schema 6)
TOPIC_SCENE = "/scene"  # foxglove.SceneUpdate, hand_base: entities SCENE_ENTITIES, metres; a viewer copy, no arrays
SCENE_OBJECT, SCENE_TARGET, SCENE_TIP_A, SCENE_TIP_B, SCENE_PLATFORM = "object", "target", "tip_a", "tip_b", "platform"
SCENE_ENTITIES = (SCENE_OBJECT, SCENE_TARGET, SCENE_TIP_A, SCENE_TIP_B, SCENE_PLATFORM)  # entity ids, stable
# Viewer copies of other topics: written as messages only, never read into arrays or columns
VIEWER_TOPICS = (TOPIC_TF, TOPIC_SCENE)
# Columns of /episode/columns under this name hold the CRC32 of each metadata record (MCAP metadata
# records carry no CRC; the columns' chunk does): "<this>:<record name>", uint32 (metadata_digest).
DIGEST_COLUMNS = "/episode/metadata_crc32"

# Per-step topics in the order the writer logs them within a step.
STEP_TOPICS = (
    TOPIC_POINTS, TOPIC_TOOL_POSE, TOPIC_TF, TOPIC_JOINTS, TOPIC_LATENT, TOPIC_ACTION,
    TOPIC_GOAL, TOPIC_REWARD, TOPIC_OBJECT, TOPIC_TARGET, TOPIC_PRIVILEGED, TOPIC_STEP,
)

# --- metadata records -------------------------------------------------------------
METADATA_EPISODE = "episode"  # written at close: the full per-episode facts
METADATA_EPISODE_START = "episode_start"  # written at open: survives a crash, used by recover

# Keys of the ``episode`` record. Values are strings (MCAP requires it); see
# ``metadata.py`` for how each is formatted and parsed.
KEY_SOURCE = "source"
KEY_TASK = "task"
KEY_OBJECT = "object"
KEY_OBJECT_KIND = "object_kind"  # (family:NAME objects) the shape drawn for the episode, e.g. "prism5"
KEY_OBJECT_DRAW = "object_draw"  # (family:NAME objects) the draw's record (JSON): object_families.rebuild takes it
KEY_SEED = "seed"
KEY_LENGTH = "length"
KEY_RETURN = "return"
KEY_SUCCESS = "success"
KEY_ATTEMPT = "attempt"
KEY_CONFIG_HASH = "config_hash"
KEY_FAILURE_REASON = "failure_reason"
KEY_TRUNCATED_FILE = "recovered"  # "true" if the file was salvaged from a cut-off write
KEY_EPISODE_ID = "episode_id"
KEY_SCHEMA_VERSION = "schema_version"
KEY_START_TIME = "start_time_s"  # episode time of the first step, seconds (not wall clock: see KEY_LOG_TIME_ORIGIN)
KEY_LOG_TIME_ORIGIN = "log_time_origin_ns"  # (v6) wall-clock ns (Unix epoch) of episode time 0; log time = it + t
KEY_END_TIME = "end_time_s"
KEY_CREATED = "created"
KEY_HINGELAB_VERSION = "hingelab_version"
KEY_GIT_COMMIT = "git_commit"
KEY_JOINT_NAMES = "joint_names"
KEY_ACTION_LEVEL = "action_level"
KEY_SUCCESS_VERDICT = "success_verdict"  # (v2) which verdict ``success`` is: a key of SUCCESS_VERDICTS
KEY_LAST_STEP_SUCCESS = "last_step_success"  # (v2) ToolShape-v0's secondary, one-frame verdict; never ``success``
KEY_OUTCOME_BY = "outcome_by"  # (v3) who judged a trial's outcome: "operator" or "simulation"
KEY_FIRST_ATTEMPT_SUCCESS = "first_attempt_success"  # ToolPick-v0 episodes and trials: success at attempt 1
KEY_REWARD_CONFIG = "reward_config"  # the env's reward config (JSON) the episode's rewards were computed with
KEY_OBJECT_PERCEPTION = "object_perception"  # (v4) the object estimator (absent: the truth with 2 mm noise)
KEY_OBJECT_NOISE = "object_noise"  # (v5) "fitted:NAME": the object observed with a fitted camera error (absent: none)
KEY_OBJECT_NOISE_MODEL = "object_noise_model_sha256"  # (v5) the fitted model file's sha256, with ``object_noise``

# The verdicts ``success`` may be (the ``success_verdict`` values): one per task, the one the
# env's info["is_success"], the demo, eval, report and the benches count.
# value -> what a report prints for it (datasets/README.md gives each one's full definition)
SUCCESS_VERDICTS = {
    # the smoothed latent z_bar averaged over the last 10 steps within the env's success threshold of z_goal
    "settled_0.5s": "settled over the last 0.5 s (ToolShape-v0)",
    # the object within 1 cm of the target (the episode ends on it; the heuristic's episodes too)
    "object_within_1cm": "object within 1 cm of the target (ToolPick-v0)",
    # (v3) robot trials judged on the terminal (hingelab trial --operator)
    "operator": "judged by the operator (robot trials)",
}
# What version-1 episodes (no ``success_verdict``) recorded as ``success``, by task
SCHEMA_V1_VERDICTS = {
    "hingelab/ToolShape-v0": "last step (ToolShape-v0, recorded before schema v2)",
    "hingelab/ToolPick-v0": "object within 1 cm of the target (ToolPick-v0, recorded before schema v2)",
}
UNNAMED_VERDICT = "as its source recorded it (no success_verdict)"


def verdict_description(verdict, task, schema_version) -> str:
    """What an episode's ``success`` counts, in words: its ``success_verdict`` (schema >= 2), else
    what its task recorded before schema 2 (``SCHEMA_V1_VERDICTS``), else ``UNNAMED_VERDICT``."""
    if isinstance(verdict, str) and verdict:
        return SUCCESS_VERDICTS.get(verdict, verdict)
    try:
        old = int(schema_version) < 2
    except (TypeError, ValueError):  # not recorded (a foreign writer): version 1's reading
        old = True
    if old and isinstance(task, str) and task in SCHEMA_V1_VERDICTS:
        return SCHEMA_V1_VERDICTS[task]
    return UNNAMED_VERDICT

REQUIRED_EPISODE_KEYS = (
    KEY_SOURCE, KEY_TASK, KEY_OBJECT, KEY_SEED, KEY_LENGTH, KEY_RETURN, KEY_SUCCESS,
    KEY_ATTEMPT, KEY_CONFIG_HASH,
)

# Channel metadata key: JSON {field: numpy dtype name} so that the per-step
# messages (which carry float fields as double) decode back to the dtypes the
# writer was given, bit for bit.
CHANNEL_DTYPES_KEY = "hingelab.dtypes"
CHANNEL_SHAPES_KEY = "hingelab.shapes"  # JSON {field: per-step shape}, e.g. {"points": [256, 3]}

# The 9 actuated DoF of the Schunk SVH, in the order of q, q-dot and 9-D actions.
SVH_JOINT_NAMES = (
    "thumb_flexion", "thumb_opposition", "index_distal", "index_proximal",
    "middle_distal", "middle_proximal", "ring", "pinky", "finger_spread",
)


# --- hingelab's own protobuf messages ---------------------------------------------
_PROTO_FILE = "hingelab/episodes_v1.proto"
_F = descriptor_pb2.FieldDescriptorProto

# (message, [(field, number, type, label, type_name)]); type_name for messages only.
_REPEATED, _OPTIONAL = _F.LABEL_REPEATED, _F.LABEL_OPTIONAL
_TS = (_F.TYPE_MESSAGE, ".google.protobuf.Timestamp")
_MESSAGES = {
    "ToolLatent": [
        ("timestamp", 1, *_TS, _OPTIONAL),
        ("z", 2, _F.TYPE_DOUBLE, None, _REPEATED),
        ("z_smoothed", 3, _F.TYPE_DOUBLE, None, _REPEATED),
    ],
    "Action": [
        ("timestamp", 1, *_TS, _OPTIONAL),
        ("values", 2, _F.TYPE_DOUBLE, None, _REPEATED),
        ("level", 3, _F.TYPE_STRING, None, _OPTIONAL),
    ],
    "LatentGoal": [
        ("timestamp", 1, *_TS, _OPTIONAL),
        ("z_goal", 2, _F.TYPE_DOUBLE, None, _REPEATED),
    ],
    "RewardTerms": [
        ("timestamp", 1, *_TS, _OPTIONAL),
        ("names", 2, _F.TYPE_STRING, None, _REPEATED),
        ("values", 3, _F.TYPE_DOUBLE, None, _REPEATED),
        ("total", 4, _F.TYPE_DOUBLE, None, _OPTIONAL),
    ],
    "PrivilegedState": [
        ("timestamp", 1, *_TS, _OPTIONAL),
        ("hinge_angle", 2, _F.TYPE_DOUBLE, None, _OPTIONAL),
        ("tool_position", 3, _F.TYPE_DOUBLE, None, _REPEATED),
        ("tool_orientation", 4, _F.TYPE_DOUBLE, None, _REPEATED),
        ("tip_a", 5, _F.TYPE_DOUBLE, None, _REPEATED),
        ("tip_b", 6, _F.TYPE_DOUBLE, None, _REPEATED),
        ("object_position", 7, _F.TYPE_DOUBLE, None, _REPEATED),
        ("object_orientation", 8, _F.TYPE_DOUBLE, None, _REPEATED),
        ("contact_count", 9, _F.TYPE_UINT32, None, _OPTIONAL),
        ("table_collision", 10, _F.TYPE_BOOL, None, _OPTIONAL),
    ],
    "Step": [
        ("timestamp", 1, *_TS, _OPTIONAL),
        ("index", 2, _F.TYPE_UINT32, None, _OPTIONAL),
        ("observation", 3, _F.TYPE_DOUBLE, None, _REPEATED),
        ("achieved_goal", 4, _F.TYPE_DOUBLE, None, _REPEATED),
        ("desired_goal", 5, _F.TYPE_DOUBLE, None, _REPEATED),
        ("action", 6, _F.TYPE_DOUBLE, None, _REPEATED),
        ("reward", 7, _F.TYPE_DOUBLE, None, _OPTIONAL),
        ("terminated", 8, _F.TYPE_BOOL, None, _OPTIONAL),
        ("truncated", 9, _F.TYPE_BOOL, None, _OPTIONAL),
        ("info_names", 10, _F.TYPE_STRING, None, _REPEATED),
        ("info_values", 11, _F.TYPE_DOUBLE, None, _REPEATED),
        ("final", 12, _F.TYPE_BOOL, None, _OPTIONAL),
    ],
    "ObjectEstimate": [
        ("timestamp", 1, *_TS, _OPTIONAL),
        ("estimator", 2, _F.TYPE_STRING, None, _OPTIONAL),
        ("position", 3, _F.TYPE_DOUBLE, None, _REPEATED),
        ("extent", 4, _F.TYPE_DOUBLE, None, _REPEATED),
        ("n_points", 5, _F.TYPE_UINT32, None, _OPTIONAL),
        ("fresh", 6, _F.TYPE_BOOL, None, _OPTIONAL),
        ("flag", 7, _F.TYPE_STRING, None, _OPTIONAL),
        ("true_position", 8, _F.TYPE_DOUBLE, None, _REPEATED),
    ],
    "Column": [
        ("name", 1, _F.TYPE_STRING, None, _OPTIONAL),
        ("dtype", 2, _F.TYPE_STRING, None, _OPTIONAL),
        ("shape", 3, _F.TYPE_UINT64, None, _REPEATED),
        ("data", 4, _F.TYPE_BYTES, None, _OPTIONAL),
    ],
    "EpisodeColumns": [
        ("timestamp", 1, *_TS, _OPTIONAL),
        ("length", 2, _F.TYPE_UINT32, None, _OPTIONAL),
        ("columns", 3, _F.TYPE_MESSAGE, ".hingelab.Column", _REPEATED),
    ],
}


def _build_messages() -> dict[str, type]:
    file_proto = descriptor_pb2.FileDescriptorProto(
        name=_PROTO_FILE, package="hingelab", syntax="proto3",
        dependency=[timestamp_pb2.DESCRIPTOR.name],
    )
    for message_name, fields in _MESSAGES.items():
        message = file_proto.message_type.add(name=message_name)
        for name, number, ftype, type_name, label in fields:
            field = message.field.add(name=name, number=number, type=ftype, label=label)
            if type_name:
                field.type_name = type_name
    pool = descriptor_pool.Default()
    try:  # already built (module reloaded): reuse, the default pool refuses duplicates
        file_descriptor = pool.FindFileByName(_PROTO_FILE)
    except KeyError:
        pool.Add(file_proto)
        file_descriptor = pool.FindFileByName(_PROTO_FILE)
    return {
        name: GetMessageClass(file_descriptor.message_types_by_name[name]) for name in _MESSAGES
    }


_CLASSES = _build_messages()
ToolLatent = _CLASSES["ToolLatent"]
Action = _CLASSES["Action"]
LatentGoal = _CLASSES["LatentGoal"]
RewardTerms = _CLASSES["RewardTerms"]
PrivilegedState = _CLASSES["PrivilegedState"]
Step = _CLASSES["Step"]
ObjectEstimate = _CLASSES["ObjectEstimate"]
Column = _CLASSES["Column"]
EpisodeColumns = _CLASSES["EpisodeColumns"]

# topic -> protobuf class of its messages
TOPIC_TYPES = {
    TOPIC_POINTS: PointCloud,
    TOPIC_TOOL_POSE: PoseInFrame,
    TOPIC_TF: FrameTransform,
    TOPIC_JOINTS: JointStates,
    TOPIC_LATENT: ToolLatent,
    TOPIC_ACTION: Action,
    TOPIC_GOAL: LatentGoal,
    TOPIC_REWARD: RewardTerms,
    TOPIC_OBJECT: Point3InFrame,
    TOPIC_TARGET: Point3InFrame,
    TOPIC_PRIVILEGED: PrivilegedState,
    TOPIC_STEP: Step,
    TOPIC_COLUMNS: EpisodeColumns,
    TOPIC_DEPTH: RawImage,
    TOPIC_CAMERA_CALIBRATION: CameraCalibration,
    TOPIC_CAMERA_POSE: FrameTransform,
    TOPIC_ARM_JOINTS: JointStates,
    TOPIC_OBJECT_ESTIMATE: ObjectEstimate,
    TOPIC_OBJECT_POINTS: PointCloud,
    TOPIC_SCENE: SceneUpdate,
}

# Schema names a hingelab episode may carry; anything else is a foreign schema.
KNOWN_SCHEMA_NAMES = frozenset(cls.DESCRIPTOR.full_name for cls in TOPIC_TYPES.values())

__all__ = [name for name in dir() if name.isupper()] + [
    "ToolLatent", "Action", "LatentGoal", "RewardTerms", "PrivilegedState", "Step", "ObjectEstimate", "Column",
    "EpisodeColumns", "PointCloud", "PoseInFrame", "FrameTransform", "JointStates",
    "Point3InFrame", "PackedElementField", "SceneUpdate", "verdict_description",
]

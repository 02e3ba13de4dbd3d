"""Rerun entity paths and timelines of hingelab recordings: the contract between the
loggers (``episode_log``, ``dataset_log``), the blueprints and the tests.

Frames: everything under ``world/`` is in the hand frame ``hand_base`` (metres, the
MCAP files' frame, see datasets/README.md); ``world/tool`` carries the registered tool
pose as a transform, so its child ``world/tool/axes`` draws the tool frame. hand_base is the
3-D view's root (not MuJoCo's world): the recorded data needs no conversion and stays where it was
recorded, the hand stays still and the arm and platform (``world/robot``) move around it.
"""

from __future__ import annotations

APPLICATION_ID = "hingelab"

# --- timelines ------------------------------------------------------------------------------
TIMELINE_STEP = "step"  # sequence: control step index within an episode (20 Hz)
TIMELINE_SIM_TIME = "sim_time"  # duration: simulated time of the step, seconds
TIMELINE_EPISODE = "episode"  # sequence: episode number within a dataset view (0, 1, ...)
TIMELINE_DATASET_STEP = "dataset_step"  # sequence: steps of all episodes of a dataset, back to back

# --- one episode (3-D, in hand_base) --------------------------------------------------------------
WORLD = "world"  # view coordinates of hand_base (static)
TOOL_CLOUD = "world/tool_cloud"  # Points3D, N per step, metres, hand_base
TOOL_FRAME = "world/tool"  # Transform3D: registered tool pose hand_base -> tool
TOOL_AXES = "world/tool/axes"  # TransformAxes3D (static) drawn in the tool frame
TIPS = "world/tips"  # Points3D, 2 per step: tip a, tip b (privileged)
OBJECT = "world/object"  # Points3D, 1 per step: object position (as observed)
TARGET = "world/target"  # Points3D, 1 per step: target position
TIP_PATH = "world/tip_path"  # LineStrips3D (static): the midpoint of the tips over the episode
ROBOT = "world/robot"  # world/robot/<body>: Mesh3D (static, body frame) + Transform3D per step (body in hand_base)
CAMERA = "world/camera"  # Transform3D per recorded frame (optical frame in hand_base) + Pinhole (static): frustum
CAMERA_DEPTH = "world/camera/depth"  # DepthImage, millimetres (trials: every --depth-every step)

# --- one episode (series and the latent plane) ----------------------------------------------------
HAND_JOINTS = "hand/joint_position"  # Scalars, 9 per step, rad
LATENT_Z = "latent/z"  # Scalars, 2 per step (z0, z1)
LATENT_Z_SMOOTHED = "latent/z_smoothed"  # Scalars, 2 per step
LATENT_Z_GOAL = "latent/z_goal"  # Scalars, 2 per step
PLANE_Z = "latent_plane/z"  # Points2D, 1 per step: the current z on the latent plane
PLANE_Z_GOAL = "latent_plane/z_goal"  # Points2D, 1 per step
PLANE_TRAJECTORY = "latent_plane/trajectory"  # LineStrips2D (static in an episode view): z over time
PLANE_REACHABLE = "latent_plane/reachable"  # LineStrips2D (static): the encoder's latent over the reachable openings
REWARD = "reward"  # reward/<term> Scalars per term, reward/total their sum
HINGE_ANGLE = "privileged/hinge_angle"  # Scalars, rad (simulator ground truth)
SUCCESS = "outcome/success"  # Scalars 0/1 per step (info is_success, else the outcome at the last step)
ATTEMPT = "outcome/attempt"  # Scalars per step (info attempt, else the episode's attempt)
EVENTS = "events"  # TextLog: attempt changes, the success or failure marker at the last step
FACTS = "episode/facts"  # TextDocument: the episode's metadata (markdown)

# --- a dataset overview (static or on the episode timeline) ---------------------------------------
OVERVIEW = "overview"
SUCCESS_BY_OBJECT = "overview/success_by_object"  # <this>/<object>: BarChart, one bar each, in SUMMARY's order
SUCCESS_BY_SOURCE = "overview/success_by_source"  # <this>/<source>: BarChart, one bar each
EPISODE_RETURN = "overview/return"  # Scalars on the episode timeline
EPISODE_LENGTH = "overview/length"  # Scalars on the episode timeline, steps
EPISODE_SUCCESS = "overview/success"  # Scalars 0/1 on the episode timeline
ALL_LATENTS = "overview/latent_plane"  # Points2D (static): every step's z of every episode
SUMMARY = "overview/summary"  # TextDocument: the tables behind the bar charts

RECORDING_ID_PREFIX = "hingelab-"

"""Real-rig episodes (``hingelab datasets import-ros2``) as high-level pre-fill transitions.

A simulated ToolPick-v0 recording carries its reward terms, the object-target distance and the
table contacts; a rig logs none of them (an imported step's ``reward`` is NaN and its
observation's target is NaN). ``real_episode_transitions`` recomputes what the env's reward needs
from what an imported episode holds, and then takes the reward from the env's own
``high_level_terms``:

* **the hand in the world**: the arm's joint angles (step infos ``arm_joint_1..6``) through MuJoCo's
  kinematics of the pick scene (``hingelab.sim.arm_kinematics``): the world is the arm's base
  frame, as in the sim, and the rig's platform is taken to stand where the scene has it;
* **the object**: ``/object/position`` (hand_base, from the bag's ``/object/pose``, or the camera's
  estimate with ``import-ros2 --object-from-cloud``) into the world
  by the hand's pose; **the target**: 5 cm above the object's position at the episode's first step
  (the env's rule, ``tool_pick.TARGET_HEIGHT`` above the object's start);
* **the grip point** (the reward's "tool"): the env's rule (``scripted.grip_point``: between the
  tip sites, at the lower tip's height) on tips rebuilt from perception: the registered tool pose
  (``/tool/pose``, leg a's frame in hand_base) and the opening the encoder's calibration reads off
  the smoothed latent (``/tool/latent`` z_bar), through the tweezer's hinge kinematics
  (``ToolGeometry.tips_in_tool_frame``). It differs from the sim's privileged grip point by the
  registration's pose error (a few mm, more in roll about the legs) and the latent's opening error
  (the calibration's reader: ``assets/checkpoints/README.md``): the tips sit 12 cm from the hinge, so
  a degree of pose error moves them by ~2 mm;
* **table collision**: a geometric rule, since a rig has no contact sensor: a rebuilt tip site
  below the top of the surface under it (the platform within its footprint, the table elsewhere).
  The tip pads are 3 mm high about the sites, so this flags a tool at least 3 mm into the surface:
  perception's few mm of error would make a stricter rule fire on every grasp near the platform.
  The sim counts any contact of arm, hand or tool with table or platform; arm and hand are not
  checked here;
* **success**: the rig's own verdict, the trial's ``success`` event (step info ``is_success``),
  as ``report`` counts it: the sparse term is ``c_h1 * is_success`` (``high_level_terms``'
  own object-within-1-cm test on the rebuilt positions is kept as the info
  ``object_within_radius``). The episode's transitions end at the first successful state
  (terminated), as the env ends an episode on success; a trial without success ends truncated.

Transition k goes from step k's observation to step k + 1's, its reward is that of the state at
step k + 1 (the env rewards the state after the action). The observation is ToolPick-v0's 14-D one:
the tool pose smoothed as the env smooths it (alpha 0.9), z_bar, the object and the target in
hand_base (the imported NaN target replaced by the computed one).

The action (``actions``): "recorded" takes the episode's ``/hingelab/action`` (the rig's high-level
command, the policy's normalized 5-D action) where every transition has a finite one in [-1, 1],
else, per episode, the reached one; "reached" always rebuilds it as ``high_level_demos`` does
for heuristic demos (the paper's rule): the latent reached at step k + 1 / 3, and the hand's
velocity measured by kinematics, ``R_hand(k+1)^T (p_hand(k+1) - p_hand(k)) / dt`` (the hand frame
after the step, as the env records it) / 0.08 m/s, clipped to [-1, 1]. A measured velocity is what
the arm did, not what it was told (the servos lag the command by a step or two).

An episode that lacks what this needs is a one-line ``DatasetError`` naming the file, what is
missing, and the topic to add to ``ros2 bag record`` (``RealEpisodeError``).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from hingelab.envs.rewards import HighLevelRewardConfig, high_level_terms
from hingelab.envs.tool_pick import TARGET_HEIGHT
from hingelab.episodes import schemas as S
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.export_trial import smoothed_pose
from hingelab.episodes.transitions import Transitions
from hingelab.perception.grip_point import grip_points_world
from hingelab.ros2.topics import ARM_JOINT_NAMES
from hingelab.sim.arm_kinematics import default_kinematics
from hingelab.tasks import MAX_SPEED, Z_SCALE

SOURCE = "real"
TOPICS = [S.TOPIC_STEP, S.TOPIC_TOOL_POSE, S.TOPIC_LATENT, S.TOPIC_OBJECT]
OBSERVATION_DIM = 14
ACTION_DIM = 5
RECORD_OBJECT = ("add /object/pose (geometry_msgs/msg/PoseStamped, the object detector's pose) to ros2 bag record, "
                 "name the bag's object topic with --topic object=NAME at import, or re-import the bag with "
                 "--object-from-cloud (the object estimated from its camera frames)")
RECORD_ARM = ("record the arm driver's JointState with arm_joint_1..6 on /joint_states (or the topic given with "
              "--topic joints=NAME)")


class RealEpisodeError(DatasetError):
    """A real episode that cannot become transitions: the file, what is missing, how to record it."""


def is_real(episode) -> bool:
    return episode.metadata.get(S.KEY_SOURCE) == SOURCE


def _arm_joints(episode, step: dict, n: int) -> np.ndarray:

    missing = [name for name in ARM_JOINT_NAMES if f"info.{name}" not in step]
    if missing:
        raise RealEpisodeError(f"{episode.path}: no arm joint angles ({', '.join(missing)}), which place the hand in "
                               f"the world; {RECORD_ARM}")
    q = np.column_stack([np.asarray(step[f"info.{name}"][:n], float) for name in ARM_JOINT_NAMES])
    bad = ~np.isfinite(q).all(axis=1)
    if bad.any():
        raise RealEpisodeError(f"{episode.path}: the arm joint angles are NaN at {int(bad.sum())} of {n} steps (no "
                               f"arm JointState stamped at or before them); {RECORD_ARM}")
    outside = default_kinematics().outside_range(q)
    if outside.any():
        raise RealEpisodeError(f"{episode.path}: the arm joint angles leave the Zu 7's joint ranges at "
                               f"{int(outside.sum())} of {n} steps; arm_joint_1..6 must be the arm's angles in rad")
    return q


def _object_hand(episode, n: int) -> np.ndarray:
    topic = episode.topics.get(S.TOPIC_OBJECT)
    bag = episode.metadata.get("ros2_bag")
    source = f" (from bag {bag})" if bag else ""
    if topic is None or "position" not in topic:
        raise RealEpisodeError(f"{episode.path}{source}: no {S.TOPIC_OBJECT} (the object's position), which the "
                               f"reward's distances and the target need; {RECORD_OBJECT}")
    obj = np.asarray(topic["position"][:n], float)
    bad = ~np.isfinite(obj).all(axis=1)
    if len(obj) < n or bad.any():
        lacking = n - len(obj) + int(bad.sum())
        estimator = episode.metadata.get(S.KEY_OBJECT_PERCEPTION)
        if estimator:  # imported with --object-from-cloud
            raise RealEpisodeError(f"{episode.path}{source}: {S.TOPIC_OBJECT} is NaN at {lacking} of {n} steps: the "
                                   f"camera's object estimate ({estimator}) had none yet (/object/estimate's flag "
                                   "says why); the object must be seen from the trial's start")
        raise RealEpisodeError(f"{episode.path}{source}: {S.TOPIC_OBJECT} is NaN at {lacking} of {n} steps (no "
                               "/object/pose stamped at or before them, or TF could not place it in hand_base); "
                               "record the object pose from the trial's start, with the TF from its frame to hand_base")
    return obj


def _perception(episode, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    pose, latent = episode.topics.get(S.TOPIC_TOOL_POSE), episode.topics.get(S.TOPIC_LATENT)
    if pose is None or latent is None or len(pose["position"]) < n or len(latent["z_smoothed"]) < n:
        raise RealEpisodeError(f"{episode.path}: no {S.TOPIC_TOOL_POSE} and {S.TOPIC_LATENT} at every step; "
                               "re-import the bag with hingelab datasets import-ros2 (the camera cloud gives them)")
    rot = Rotation.from_quat(np.asarray(pose["orientation"][:n], float)).as_matrix()  # x y z w
    return np.asarray(pose["position"][:n], float), rot, np.asarray(latent["z_smoothed"][:n], float)


def real_episode_transitions(episode, index: int, config: HighLevelRewardConfig, calibration, actions: str = "recorded",
                             observation_dim: int = OBSERVATION_DIM) -> Transitions:
    """One imported real episode -> ToolPick-v0 transitions with the env's reward (module docstring).

    Infos per transition: ``is_success`` (the rig's), ``object_within_radius`` (the geometric one),
    ``tool_object_distance``, ``object_target_distance`` (m), ``table_collision``, ``demo_action_recorded``
    (1: the rig's recorded action, 0: the reached one)."""

    path = episode.path
    if observation_dim != OBSERVATION_DIM:
        raise RealEpisodeError(f"{path}: a real episode observes no object extent; train without observe_extent "
                               f"(its observations are {OBSERVATION_DIM}-D, the run's {observation_dim}-D)")
    step = episode.topics.get(S.TOPIC_STEP, {})
    obs = step.get("observation")
    if obs is None or obs.shape[1:] != (OBSERVATION_DIM,):
        raise RealEpisodeError(f"{path}: its /step observations are not ToolPick-v0's {OBSERVATION_DIM}-D ones; "
                               "re-import the bag with hingelab datasets import-ros2")
    n = len(obs)
    if n < 2:
        raise RealEpisodeError(f"{path}: {n} step(s), no transition")
    arm_q = _arm_joints(episode, step, n)
    obj_hand = _object_hand(episode, n)
    tool_pos, tool_rot, z_bar = _perception(episode, n)
    kin = default_kinematics()
    hand_rot, hand_pos = kin.hand_poses(arm_q)
    obj_world = np.einsum("tij,tj->ti", hand_rot, obj_hand) + hand_pos
    target = obj_world[0] + np.array([0.0, 0.0, TARGET_HEIGHT])
    grip, tip_a, tip_b = grip_points_world(tool_pos, tool_rot, z_bar, hand_rot, hand_pos, calibration)
    tips = np.stack([tip_a, tip_b], axis=1)  # (T, 2, 3)
    collision = (tips[..., 2] < kin.surface_top_z(tips[..., :2])).any(axis=1)
    rig_success = np.asarray(step.get("info.is_success", np.zeros(n))[:n], float) > 0.5
    terms = [high_level_terms(grip[k], obj_world[k], target, bool(collision[k]), config) for k in range(n)]
    dense = np.array([t["tool_object"] + t["object_target"] + t["penalty"] for t in terms])
    reward_of_state = dense + (config.c_h1 + config.absorbing_bonus) * rig_success  # the rig's verdict
    # transitions k = 0..m-1 (state k -> k + 1), up to the first successful state
    if rig_success[0]:
        raise RealEpisodeError(f"{path}: the trial's success event comes before its first step; no transition")
    hits = np.flatnonzero(rig_success)
    m = int(hits[0]) if len(hits) else n - 1
    target_hand = np.einsum("tji,tj->ti", hand_rot, target - hand_pos)  # R^T (target - p)
    observation = np.array(obs, float, copy=True)
    observation[:, :6] = smoothed_pose(observation[:, :6])  # the env's smoothing, as the trials' export
    observation[:, 11:14] = target_hand
    recorded = np.asarray(step.get("action", np.full((n, ACTION_DIM), np.nan)), float)[:m]
    use_recorded = (actions == "recorded" and recorded.shape[1:] == (ACTION_DIM,) and np.isfinite(recorded).all()
                    and np.abs(recorded).max() <= 1.0 + 1e-9)
    if use_recorded:
        action = recorded.copy()
    else:
        dt = np.diff(step["log_time_ns"][:m + 1]) / 1e9
        moved = np.einsum("tji,tj->ti", hand_rot[1:m + 1], hand_pos[1:m + 1] - hand_pos[:m]) / dt[:, None]
        action = np.clip(np.concatenate([z_bar[1:m + 1] / Z_SCALE, moved / MAX_SPEED], axis=1), -1.0, 1.0)
    d_tool = np.linalg.norm(grip - obj_world, axis=1)
    d_target = np.linalg.norm(obj_world - target, axis=1)
    nxt = slice(1, m + 1)
    terminated = np.zeros(m, bool)
    truncated = np.zeros(m, bool)
    if len(hits):
        terminated[-1] = True
    else:
        truncated[-1] = True
    return Transitions(
        observations=observation[:m], next_observations=observation[nxt], actions=action,
        rewards=reward_of_state[nxt], terminated=terminated, truncated=truncated,
        infos={"is_success": rig_success[nxt].astype(float),
               "object_within_radius": (d_target[nxt] < config.success_radius).astype(float),
               "tool_object_distance": d_tool[nxt], "object_target_distance": d_target[nxt],
               "table_collision": collision[nxt].astype(float),
               "demo_action_recorded": np.full(m, float(use_recorded))},
        episode_index=np.full(m, index, dtype=np.int64))


__all__ = ["RealEpisodeError", "real_episode_transitions", "is_real", "TOPICS", "SOURCE"]

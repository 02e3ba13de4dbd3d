"""The paper's rewards, vectorized (batches of goals for HER).

Low level (paper eq. 3-5):
    r_goal   = exp(-c1 ||z_bar - z_goal||)
    r_effort = -c2 mean_i ||T(v_bar, w_bar) p_i - p_i|| - c3 ||qdot||
              [- c4 max(0, drift - drift_free)]  (not the paper's: off unless c4 > 0)
where T moves the canonical cloud's points p_i by one control step of the smoothed tool
velocity (v in m/s, w in rad/s, both hand frame). The paper sums over the points; we
average (the sum is N times the mean, N = 256: c2 absorbs it) so c2 does not depend on
the cloud size. The optional drift term is a training-time shaping on privileged state: the
true distance of the tool from where the episode started it in the hand (``info["tool_drift_m"]``),
the quantity the low level's "tool < 1 cm" goal measures. The paper's motion term sees only
the perceived, noisy per-step velocity; the drift term charges what accumulates. The policy's
observation is unchanged.

High level (paper eq. 8-10):
    r = c_h1 [success] + exp(-c_h2 ||tool - object||) + c_h3 exp(-c_h4 ||object - target||)
        - c_h5 [tool-object or object-target distance > 20 cm, or table collision]
        [+ gamma R_max / (1 - gamma) [success]]   (mode "absorbing", the default; not the paper's)
"tool" is the point between the tweezer tips (the working point the paper's tool
position stands for; the registered tool frame sits on the hinge, 12 cm behind them).

Why the absorbing term: both shaping terms are positive at every step (up to R_max = 1 + c_h3),
success pays c_h1 once and ends the episode, and the 200-step limit bootstraps. Under the paper's
reward alone a policy holding the object 1.1 cm short of the target is worth about
1.8 / (1 - gamma) = 90 to a critic with gamma 0.98, one that succeeds about 12: lingering pays more
than finishing. Mode "absorbing" treats success as an absorbing state: the terminal step also
carries the discounted value of staying at the target forever at the best step reward,
gamma R_max / (1 - gamma), so a success is worth more than any lingering, and ending the episode by
dropping the tool (which forfeits the positive shaping) stays worth the least. ``gamma`` must be the
learner's discount (the training configs pass theirs). Mode "paper" is eq. 8-10 alone.
``analysis/high-level/reward/`` measures both on a successful and a hovering episode
(``hingelab.analysis.reward_diagnostic``).
"""

from __future__ import annotations

import math

import numpy as np

from hingelab.envs.reward_config import (  # noqa: F401  (the reward settings, here as before)
    HIGH_LEVEL_REWARD_MODES,
    LEGACY_MODE,
    HighLevelRewardConfig,
    LowLevelRewardConfig,
)
from hingelab.errors import ConfigError
from hingelab.perception import pose_kernels
from hingelab.perception.registration import rotvec_to_matrix


def goal_reward(z_bar: np.ndarray, z_goal: np.ndarray, c1: float) -> np.ndarray:
    """exp(-c1 ||z_bar - z_goal||) over the last axis; broadcasts batches of goals."""
    return np.exp(-c1 * np.linalg.norm(np.asarray(z_bar) - np.asarray(z_goal), axis=-1))


def effort_quantities(v_bar: np.ndarray, w_bar: np.ndarray, qdot: np.ndarray, canonical_points: np.ndarray,
                      control_dt: float) -> tuple[float, float]:
    """The effort term's unweighted parts: (mean displacement of the canonical points by one
    control step of the smoothed tool motion, m; finger speed ||qdot||, rad/s).

    Envs record these in ``info`` (``tool_motion_m``, ``finger_speed``) so that a dataset's
    rewards can be recomputed for any weights c2, c3 (``effort_from_info``)."""
    rot = rotvec_to_matrix(np.asarray(w_bar, float)[None] * control_dt)[0]
    shift = np.asarray(v_bar, float) * control_dt
    moved = pose_kernels.mean_displacement(np.ascontiguousarray(canonical_points, dtype=float), rot, shift)
    qdot = np.asarray(qdot, float)
    return float(moved), math.sqrt(qdot @ qdot)  # np.linalg.norm's formula for a vector, without its overhead


def effort_terms(tool_motion_m, finger_speed, config: LowLevelRewardConfig):
    """(tool-motion term, finger-speed term), both <= 0, from the unweighted quantities (scalars or arrays)."""
    return -config.c2 * tool_motion_m, -config.c3 * finger_speed


def drift_term(tool_drift_m, config: LowLevelRewardConfig):
    """The drift term, <= 0: ``-c4 max(0, drift - drift_free_m)`` (scalar or array of drifts, m)."""
    return -config.c4 * np.maximum(0.0, np.asarray(tool_drift_m, float) - config.drift_free_m)


def effort_from_info(info, config: LowLevelRewardConfig):
    """The effort term (with the drift term when c4 > 0) for one info dict, a dict of arrays,
    or a list of dicts (HER's batches).

    From the recorded ``tool_motion_m`` and ``finger_speed`` (and ``tool_drift_m``) with this
    config's weights; an info without them (recorded before they were) gives its recorded
    ``effort``, which is right only for the weights it was recorded with (``relabel_rewards``
    checks that)."""
    if isinstance(info, dict):
        if "tool_motion_m" in info and "finger_speed" in info:
            tool, fingers = effort_terms(np.asarray(info["tool_motion_m"], float),
                                         np.asarray(info["finger_speed"], float), config)
            if config.c4 > 0:
                if "tool_drift_m" not in info:
                    raise ConfigError("the drift term (drift weight c4 > 0) needs the tool drift (info "
                                      "'tool_drift_m'), which these transitions do not record")
                return tool + fingers + drift_term(info["tool_drift_m"], config)
            return tool + fingers
        return info.get("effort", 0.0)
    return np.array([float(effort_from_info(i, config)) for i in info], dtype=float)


def high_level_terms(tool: np.ndarray, obj: np.ndarray, target: np.ndarray, table_collision: bool,
                     config: HighLevelRewardConfig) -> dict[str, float]:
    """The high-level reward's terms (metres in, any common frame); their sum is the reward."""
    d_tool = float(np.linalg.norm(np.asarray(tool) - obj))
    d_target = float(np.linalg.norm(np.asarray(obj) - target))
    success = d_target < config.success_radius
    penalty = d_tool > config.far or d_target > config.far or bool(table_collision)
    return {
        "sparse": config.c_h1 * float(success),
        "tool_object": float(np.exp(-config.c_h2 * d_tool)),
        "object_target": config.c_h3 * float(np.exp(-config.c_h4 * d_target)),
        "penalty": -config.c_h5 * float(penalty),
        "absorbing": config.absorbing_bonus * float(success),
    }

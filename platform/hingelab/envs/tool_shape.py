"""``hingelab/ToolShape-v0``: the low-level task, shaping the tweezer to a latent goal.

## Description
The SVH hand (base fixed in space) holds the tweezer in its ``grasp`` keyframe. The
policy moves the 9 finger channels so that the tool's smoothed latent z_bar (PointNet
encoder of the synthesized, noisy, partly occluded cloud) reaches a goal latent, while
the tool stays still in the hand (paper, "Low-level Policy").

## Action Space
``Box(-1, 1, (9,))``: relative joint-position changes of the 9 SVH channels, scaled by
``action_scale`` (0.05 rad per 50 ms step, i.e. up to 1 rad/s), in the driver's channel
order: thumb flexion, thumb opposition, index distal, index proximal, middle distal,
middle proximal, ring, pinky, spread. Target = current position + change (clipped to
the joint ranges).

## Observation Space
``Dict``: ``observation`` (26,) = hand q (9, rad) and q-dot (9, rad/s) through the
episode's sensor delay, tool v_bar (3, m/s) and omega_bar (3, rad/s) in hand_base, z_bar
(2); ``achieved_goal`` (2,) = z_bar; ``desired_goal`` (2,) = z_goal.

## Rewards
``exp(-c1 ||z_bar - z_goal||)`` (goal) plus the effort term ``-c2 mean ||T(v_bar, omega_bar)
p - p|| - c3 ||qdot||`` over the canonical cloud's points (``use_effort=False`` drops it: the
paper's ablation). ``drift_weight`` c4 > 0 adds ``-c4 max(0, drift - 5 mm)`` on the privileged
drift of the tool from its start in the hand (training shaping, not the paper's; off by default).
See ``hingelab.envs.rewards``. ``compute_reward`` is vectorized over
goals (HER relabels with it; the effort is goal-free and read back from ``info``).

## Goals
``goal_sampling="normal"``: z_goal ~ N(0, I), the paper's choice. ``"reachable"``: z_goal =
the calibrated latent of an opening drawn uniformly over the hinge range the fingers can
reach. Why it matters: the encoder's latents of real tweezer shapes lie near a 1-D curve
in the 2-D plane; most N(0, I) goals are off that curve, so no finger motion achieves
them and success (a small latent distance) is impossible for them: training spends most
episodes on unreachable goals and success rates measure the goal sampler as much as the
policy. HER relabels with achieved (hence reachable) latents either way. ``"reachable_open"``:
as ``"reachable"``, but half of the openings are drawn from the open 40% of the range, where
the grasp holds the tool most loosely (a training option: more practice where goals are missed).
``"reachable_closed"``: half of the openings from the closed 25% of the range, where a policy
that squeezes the tweezer shut misses goals of 1-3 mm of tip gap (the same kind of option).
``goal_openings=(low, high)`` (rad): the reachable goals only from that band of openings (within
the reachable range), to train an expert for one band (``hingelab compose low`` routes goals to it).

## Success
One verdict, ``info["is_success"]`` (the episode's recorded ``success``, with metadata
``success_verdict`` = ``"settled_0.5s"``: ``hingelab.episodes.schemas``): z_bar **settled**, i.e.
the mean of z_bar over the last ``SETTLE_STEPS`` = 10 steps (0.5 s at 20 Hz; fewer in an
episode's first steps, and at reset the reset's z_bar alone), within ``success_threshold`` of
z_goal (``info["settled_latent_distance"]`` is that mean's distance). The env keeps that window
itself. Why not one frame: at rest the in-hand latent jitters from frame to frame by about the
threshold itself, so one frame's verdict measures the camera as much as the policy (measured in
``analysis/low-level-ablation/README.md``). The one-frame verdict stays as a secondary field,
never the success: ``info["last_step_success"]`` (``||z_bar - z_goal|| < success_threshold`` at
this step; ``info["latent_distance"]`` its distance). The threshold's default is the latent
distance that 2 mm of tip gap spans along the calibration curve (mid-range), so success means
"the tips are within about 2 mm of the opening asked for", a precision that matters for 1.5 to
2.5 cm objects; computed from the encoder's calibration at construction
(``info["success_threshold"]``). The reward and ``compute_reward`` (hence HER's relabelling) do
not use the verdict: they read z_bar of the step (and the effort from ``info``) only.

## Episode End
Truncated after ``max_episode_steps`` (50 = 2.5 s, the time limit wrapper) or when the
simulation diverges (``info["diverged"]``, failure reason "divergence"); terminated early
only if the tool leaves the hand (more than 3 cm from its start: ``info["dropped"]``;
``terminate_on_drop=False`` reports it and runs on to the time limit). Never on success
(HER convention).

## Arguments
``use_effort`` (True), ``goal_sampling`` ("normal"), ``randomize`` (True: delays up to 150
ms, gains 60-150%, friction 0.2-1 per finger segment), ``success_threshold`` (None:
calibrated), ``action_scale`` (0.05), ``encoder_path`` (None: shipped), ``realistic_clouds``
(True: 3 mm noise, 20% occlusion, per-episode pose error), ``effort_weight`` (None: c2 = 50 per m of
mean point displacement per step; the weight of the tool-motion part of the effort), ``drift_weight`` (0:
off; c4 per m of tool drift beyond 5 mm, per step), ``smoothing_alpha`` (0.9: the EMA
weight of the newest v, omega, z; 0.1 smooths over ~10 steps and cuts the latent's
frame-to-frame jitter to about a quarter), ``terminate_on_drop`` (True).

## Version History
v0: first version (later options that default to v0's behaviour: ``effort_weight``,
``drift_weight``, ``goal_openings``, ``goal_sampling="reachable_open"`` and ``"reachable_closed"``).
v0, from episode schema 2: ``info["is_success"]`` is the settled verdict (z_bar over the last
0.5 s); episodes of schema 1 recorded the last step's z_bar alone as ``success`` (the verdict of
``info["last_step_success"]``). Recorded episodes name their verdict (``success_verdict``).
Observations, dynamics, the reward and ``compute_reward`` are the same in both, so the id stays v0;
``hingelab report`` says which verdict a version-1 episode's ``success`` is.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np

from hingelab.envs.rendering import SimRenderMixin
from hingelab.envs.rewards import (
    LowLevelRewardConfig,
    drift_term,
    effort_from_info,
    effort_quantities,
    effort_terms,
    goal_reward,
)
from hingelab.errors import ConfigError
from hingelab.perception.calibration import latent_distance_for_gap
from hingelab.perception.clouds import ToolGeometry
from hingelab.perception.encoder import load_encoder
from hingelab.perception.tool_perception import ToolPerception, camera_for
from hingelab.sim.core import SimCore
from hingelab.sim.finger_synergy import FingerSynergy
from hingelab.sim.randomization import RandomizationConfig
from hingelab.tasks import TOOL_SHAPE_ID, task_spaces
from hingelab.tasks import TOOL_SHAPE_SUCCESS_GAP_MM as SUCCESS_GAP_MM

GOAL_SAMPLERS = ("normal", "reachable", "reachable_open", "reachable_closed")
OPEN_SHARE = 0.4  # "reachable_open": the top part of the reachable range that gets half of the goals
CLOSED_SHARE = 0.25  # "reachable_closed": the bottom part of the reachable range that gets half of the goals
DROP_DISTANCE_M = 0.03
SETTLE_STEPS = 10  # the last 0.5 s at 20 Hz: the success verdict's window (where the policy holds the tool)
SUCCESS_VERDICT = "settled_0.5s"  # the metadata value of success_verdict (hingelab.episodes.schemas.SUCCESS_VERDICTS)
CANONICAL_OPENING = 0.15  # rad: the canonical cloud the effort term moves


class ToolShapeEnv(SimRenderMixin, gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}
    success_verdict = SUCCESS_VERDICT  # what info["is_success"] means; recorded with every episode

    def __init__(self, use_effort: bool = True, goal_sampling: str = "normal", randomize: bool = True,
                 success_threshold: float | None = None, action_scale: float = 0.05,
                 encoder_path: str | None = None, realistic_clouds: bool = True,
                 reward: LowLevelRewardConfig | None = None, render_mode: str | None = None,
                 smoothing_alpha: float = 0.9, terminate_on_drop: bool = True, effort_weight: float | None = None,
                 drift_weight: float = 0.0, goal_openings: tuple[float, float] | None = None,
                 perception: str = "synthesized"):
        if goal_sampling not in GOAL_SAMPLERS:
            raise ConfigError(f"goal_sampling {goal_sampling!r} is unknown; choose one of {GOAL_SAMPLERS}")
        if not 0 < action_scale <= 0.5:
            raise ConfigError(f"action_scale {action_scale} rad per step is out of range (0, 0.5]")
        self.sim = SimCore("tool_shape", randomization=RandomizationConfig(enabled=randomize),
                           camera=camera_for(perception))
        self.perception = ToolPerception(load_encoder(encoder_path), realistic=realistic_clouds,
                                         dt=self.sim.control_dt, alpha=smoothing_alpha, perception=perception)
        self.calibration = self.perception.calibration
        if self.calibration is None:
            raise ConfigError("the encoder checkpoint has no latent-opening calibration; "
                              "retrain it with `hingelab train encoder`")
        self.reward_config = reward or LowLevelRewardConfig(use_effort=use_effort, control_dt=self.sim.control_dt)
        if reward is not None and reward.use_effort != use_effort:
            self.reward_config = LowLevelRewardConfig(**{**reward.__dict__, "use_effort": use_effort})
        if effort_weight is not None:
            if not effort_weight >= 0:
                raise ConfigError(f"effort_weight (c2) must be >= 0, got {effort_weight}")
            self.reward_config = LowLevelRewardConfig(**{**self.reward_config.__dict__, "c2": float(effort_weight)})
        if drift_weight:
            if not drift_weight > 0:
                raise ConfigError(f"drift_weight (c4) must be >= 0, got {drift_weight}")
            self.reward_config = LowLevelRewardConfig(**{**self.reward_config.__dict__, "c4": float(drift_weight)})
        self.goal_sampling = goal_sampling
        self.action_scale = action_scale
        self.terminate_on_drop = terminate_on_drop
        self.reachable_range = FingerSynergy.load().theta_range
        self.goal_openings = self._goal_band(goal_openings, goal_sampling)
        self.success_threshold = (success_threshold if success_threshold is not None
                                  else latent_distance_for_gap(self.calibration, SUCCESS_GAP_MM))
        self.canonical_points = ToolGeometry.default().canonical_cloud(CANONICAL_OPENING, 256)
        self.render_mode = render_mode
        self.observation_space, self.action_space = task_spaces(TOOL_SHAPE_ID)
        self.goal = np.zeros(2)
        # the smoothed latents of the last SETTLE_STEPS steps (a ring; _settled_count since reset)
        self._settle_window = np.zeros((SETTLE_STEPS, 2))
        self._settled_count = 0
        self.sample = None
        self.start_state = None
        self.state = None
        self.last_record: dict = {}

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        episode_seed = int(self.np_random.integers(2**31))
        self.state = self.start_state = self.sim.reset(seed=episode_seed)
        self.perception.reset(episode_seed)
        self.goal = self._sample_goal() if not (options and "goal" in options) else np.asarray(options["goal"], float)
        self.sample = self.perception.observe(self.sim)
        self._settled_count = 0  # the window holds the steps' latents; at reset, the verdict reads this one
        obs = self._observation()
        terms = {"goal": 0.0, "effort_tool": 0.0, "effort_fingers": 0.0}
        if self.reward_config.use_effort and self.reward_config.c4 > 0:
            terms["drift"] = 0.0  # the steps' terms, so that every recorded field has a row per message
        info = self._info(terms=terms)
        self.last_record = self._record(None, 0.0, info)
        return obs, info

    def step(self, action):
        action = np.asarray(action, dtype=float)
        # a finite sum of squares proves every value finite; only a non-finite one needs the full test
        if action.shape != (9,) or not (math.isfinite(action @ action) or np.isfinite(action).all()):
            raise ConfigError(f"ToolShape-v0 takes 9 finite values in [-1, 1], got {action!r}")
        # np.minimum(np.maximum()) is np.clip's arithmetic without its dispatch cost
        result = self.sim.step(hand_action=np.minimum(np.maximum(action, -1.0), 1.0) * self.action_scale)
        self.state = result.state
        self.sample = self.perception.observe(self.sim)
        self._settle_window[self._settled_count % SETTLE_STEPS] = self.sample.z_smoothed[0]
        self._settled_count += 1
        obs = self._observation()
        qdot = self.sim.hand.qdot(self.sim.data)
        goal = float(goal_reward(obs["achieved_goal"], self.goal, self.reward_config.c1))
        c = self.reward_config
        motion, speed = effort_quantities(self.sample.velocity_smoothed[0], self.sample.angular_velocity_smoothed[0],
                                          qdot, self.canonical_points, c.control_dt)
        tool_term, finger_term = effort_terms(motion, speed, c) if c.use_effort else (0.0, 0.0)
        terms = {"goal": goal, "effort_tool": tool_term, "effort_fingers": finger_term}
        info = self._info(terms)
        if c.use_effort and c.c4 > 0:  # a term of its own, so that recorded terms still sum to the reward
            terms["drift"] = float(drift_term(info["tool_drift_m"], c))
            info["effort"] += terms["drift"]
        # unweighted, so that recorded rewards can be recomputed for other weights (relabel_rewards)
        info["tool_motion_m"], info["finger_speed"] = motion, speed
        info["diverged"] = result.diverged
        reward = goal + tool_term + finger_term + terms.get("drift", 0.0)
        terminated = bool(info["dropped"]) and not result.diverged and self.terminate_on_drop
        info["perception_flag"] = self.perception.flag
        blind = self.perception.flag is not None  # the camera gave no cloud: end the episode, keep what it did
        truncated = bool(result.diverged) or (blind and not terminated)  # void episodes, not task outcomes
        if result.diverged:
            info["failure_reason"] = "divergence"
        elif blind and not terminated:
            info["failure_reason"] = "no_camera_cloud"
        elif info["dropped"]:
            info["failure_reason"] = "drop"
        self.last_record = self._record(action, reward, info)
        return obs, reward, terminated, truncated, info

    def compute_reward(self, achieved_goal, desired_goal, info):
        """Vectorized: (B, 2) goals and a list/array of info dicts (or one dict) -> (B,) rewards."""
        goal = goal_reward(achieved_goal, desired_goal, self.reward_config.c1)
        if not self.reward_config.use_effort:
            return goal
        return goal + effort_from_info(info, self.reward_config)

    def _camera(self):
        return self.sim.data.body("hand_base").xpos, 0.45, 120, -20

    # ------------------------------------------------------------------ parts
    def _goal_band(self, band, goal_sampling: str) -> tuple[float, float] | None:
        """The (low, high) openings goals are drawn from, within the reachable range; None: all of it."""
        if band is None:
            return None
        low, high = (float(v) for v in band)
        reach_low, reach_high = self.reachable_range
        if goal_sampling != "reachable":
            raise ConfigError(f"goal_openings needs goal_sampling='reachable', not {goal_sampling!r}")
        if not (low < high and low < reach_high and high > reach_low):
            raise ConfigError(f"goal_openings {band} is not a band inside the reachable openings "
                              f"{reach_low:.3f}..{reach_high:.3f} rad (give low < high)")
        return max(low, reach_low), min(high, reach_high)

    def _sample_goal(self) -> np.ndarray:
        if self.goal_sampling == "normal":
            return self.np_random.normal(size=2)
        low, high = self.goal_openings or self.reachable_range
        if self.goal_sampling == "reachable_open" and self.np_random.random() < 0.5:
            low = high - OPEN_SHARE * (high - low)
        elif self.goal_sampling == "reachable_closed" and self.np_random.random() < 0.5:
            high = low + CLOSED_SHARE * (high - low)
        opening = self.np_random.uniform(low, high)
        return np.asarray(self.calibration.z_for_opening(opening), float)

    def _observation(self) -> dict:
        q, qdot = self.sim.hand_observation()
        s = self.sample
        z_bar = s.z_smoothed[0]
        obs = np.concatenate([q, qdot, s.velocity_smoothed[0], s.angular_velocity_smoothed[0], z_bar])
        return {"observation": obs, "achieved_goal": z_bar.copy(), "desired_goal": self.goal.copy()}

    def _info(self, terms: dict) -> dict:
        # sqrt(x @ x) is np.linalg.norm's own formula for a vector, without its call overhead
        moved = self.state.tool_pos_hand - self.start_state.tool_pos_hand
        drift = math.sqrt(moved @ moved)
        z_bar = self.sample.z_smoothed[0]
        apart = z_bar - self.goal
        distance = math.sqrt(apart @ apart)
        n = min(self._settled_count, SETTLE_STEPS)
        settled = self._settle_window[:n].sum(axis=0) / n if n else z_bar
        apart = settled - self.goal
        settled_distance = math.sqrt(apart @ apart)
        return {
            "is_success": float(settled_distance < self.success_threshold),  # the one verdict: settled
            "settled_latent_distance": settled_distance,
            "last_step_success": float(distance < self.success_threshold),  # secondary: this frame alone
            "latent_distance": distance,
            "success_threshold": self.success_threshold,
            "effort": terms["effort_tool"] + terms["effort_fingers"],
            "reward_terms": terms,
            "hinge_angle": self.state.hinge_angle,
            "tool_drift_m": drift,
            "dropped": drift > DROP_DISTANCE_M,
        }

    def _record(self, action, reward: float, info: dict) -> dict:
        """What the recording wrapper writes for this step (see ``hingelab.envs.recording``)."""
        s = self.sample
        return {
            "cloud": self.perception.cloud, "tool_rotation": s.rotation[0], "tool_position": s.position[0],
            "latent_z": s.z[0], "latent_z_smoothed": s.z_smoothed[0], "goal_z": self.goal,
            "action": None if action is None else np.asarray(action, float), "reward_terms": info["reward_terms"],
            "privileged": self.state, "object_position_hand": None, "target_position_hand": None,
        }

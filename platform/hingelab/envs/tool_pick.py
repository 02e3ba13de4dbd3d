"""``hingelab/ToolPick-v0``: the high-level task, picking an object with the tweezer.

## Description
The Zu 7 arm carries the SVH hand holding the tweezer over a 20 cm platform. An object
(by default the 1 cm radius, 10 g training sphere) lies at a random spot of a 10 x 10 cm
area; the target is 5 cm above it. The high level sets the tool's latent goal for the
low level and the hand's velocity (paper, "High-level Policy"); the low level inside is
frozen: the privileged one (hinge driven to the opening the goal calibrates to) or a
trained low-level policy checkpoint.

## Action Space
``Box(-1, 1, (5,))``: ``[z_goal (2) / z_scale, hand velocity (3) / max_speed]``; z_scale 3
(latents are ~N(0, I)), max_speed 0.08 m/s; the velocity is in the hand frame and goes to
the arm through the Jacobian pseudoinverse.

## Observation Space
``Box(14,)``: tool t_bar (3, m) and Euler theta_bar (3, rad, xyz) from registration,
smoothed; z_bar (2); object position (3, m: the object's centre, as a camera reports it, not its
body origin, which for a tetrahedron is on its base; with 2 mm Gaussian noise, or the depth
camera's estimate with ``object_perception``) and target position (3, m); all in the hand frame,
through the episode's observation delay. With ``observe_extent``, ``Box(17,)``: then the object's
extent (3, m: its bounding box along the world axes, as a camera's detection gives it, with 2 mm
Gaussian noise, or the camera estimate's visible extent), which the scripted high level's opening,
grip height and hinge angle depend on.

## Rewards
``c_h1 [success] + exp(-c_h2 ||tool - object||) + c_h3 exp(-c_h4 ||object - target||) - c_h5
[a distance > 20 cm or a table collision]``, tool = the point between the tips
(``hingelab.envs.rewards``); the terms are in ``info["reward_terms"]``.

## Episode End
Terminated on success (object within 1 cm of the target) or when the tool leaves the hand
(more than 3 cm from its in-hand start, ``info["tool_dropped"]``, failure reason
"tool_drop": the paper's tool is fixed in the hand, and the steps of a tool lying on the
table teach nothing and track nothing; ``terminate_on_drop=False`` reports it and runs on);
truncated after ``max_episode_steps`` (200 = 10 s, the paper's limit), when the simulation
diverges (failure reason "divergence"), when a camera frame gives no tool cloud ("no_camera_cloud")
or when the camera has not estimated the object yet ("no_object_estimate", ``object_perception``).
A failed grasp does not end the episode: the object stays where it fell and the next grasp is attempt 2
(``info["attempt"]``; ``info["first_attempt_success"]``).

## Arguments
``object`` ("sphere"; a shape of ``hingelab.sim.objects.SHAPES``, or "mesh:PATH" for an STL, OBJ or
PLY file scaled so its largest extent is ``size``: ``hingelab.sim.mesh_objects``; or "family:NAME[:SEED]",
a new object drawn at every reset from a procedural family, ``size`` its cap and ``mass`` unused:
``hingelab.sim.object_families``; ``object_record`` is then the episode's draw), ``size`` (0.02 m),
``mass`` (0.01 kg), ``low_level`` ("privileged";
"policy": the shipped low-level policy ``assets/checkpoints/low_level_experts.json``; or a checkpoint
path), ``randomize`` (True: object friction 1-5, finger friction, gains
60-150% of hand and arm servos, observation delays up to 150 ms), ``placement_half_width``
(0.05 m), ``max_episode_steps`` (200), ``encoder_path``, ``terminate_on_drop`` (True), ``observe_extent`` (False),
``perception`` ("synthesized" tool clouds, or "camera": ``hingelab.perception.tool_perception``),
``object_perception`` ("truth": the true centre and extent with 2 mm noise; or an object estimator,
"centroid" (the paper's), "ray_corrected", "primitive_fit", on the camera's frame, which needs
``perception="camera"``: ``hingelab.perception.object_perception``; the estimate and the truth are in
``last_record["object_estimate"]``), ``object_noise`` ("gaussian": the 2 mm Gaussian of ``object_perception="truth"``;
"fitted:ESTIMATOR": the camera's error without rendering, drawn from the fitted model of
``hingelab.perception.object_noise_model``, ``object_noise_model`` its file (default the one under
``analysis/objects/noise-model/``): the centre as truth + the estimator's bias and noise in the rig camera's ray
frame, dropouts keeping the last estimate, the extent from its extent fit; only with ``object_perception="truth"``),
``pick_set_weights`` (None: ``family:picksets`` draws its 12 sets uniformly; ``{"SHAPE:SIZE": weight}``, e.g.
``{"tetrahedron:0.015": 4}``, an unnamed set weighing 1: a curriculum toward the sets a policy misses;
``hingelab.sim.object_families.pick_set_weights``), ``tool_position`` (the form of the observed tool pose:
"observed", the tracked pose, the paper's; "anchored", the tracked position's change since the episode's first frame
on the nominal in-hand position; "relative", the whole pose's change in the tool's first-frame axes on the nominal
pose, its Euler angles near zero; "nominal", the nominal in-hand pose, no tracking:
``hingelab.perception.observed_tool_pose``), ``hand_eye`` (with
``perception="camera"``: "calibrated", the camera pose with its calibration error, or "refined", corrected on each
episode's first frame from the robot's own points: ``hingelab.perception.hand_eye``).

## Version History
v0: first version. Changed within v0: the observed object position is the centre, not the body
origin (the same observation for the sphere, cube, cylinder and meshes); ``object`` may be a family.
``object_perception`` (default "truth": the observation as before). ``object_noise`` (default "gaussian": the
observation as before). ``pick_set_weights`` (default None: the draws as before). ``tool_position`` (default
"observed": the observation as before; "relative" and "nominal" added later). ``hand_eye`` (default "calibrated":
the camera as before)."""

from __future__ import annotations

from dataclasses import replace

import gymnasium as gym
import numpy as np

from hingelab.envs.low_level import PolicyLowLevel, PrivilegedLowLevel
from hingelab.envs.rendering import SimRenderMixin
from hingelab.envs.rewards import HighLevelRewardConfig, high_level_terms
from hingelab.envs.tool_shape import DROP_DISTANCE_M
from hingelab.errors import ConfigError
from hingelab.perception.encoder import load_encoder
from hingelab.perception.object_noise_model import GAUSSIAN, fitted_estimator, make_fitted
from hingelab.perception.object_perception import TRUTH, CameraObjectEstimate, check_object_perception_with
from hingelab.perception.observed_tool_pose import OBSERVED, ObservedToolPose, check_tool_position
from hingelab.perception.tool_perception import CALIBRATED, ToolPerception, camera_for
from hingelab.policies.low_level import SHIPPED_LOW_LEVEL
from hingelab.sim import scripted
from hingelab.sim.core import SimCore
from hingelab.sim.delay import DelayLine
from hingelab.sim.object_families import ObjectFamily, is_family
from hingelab.sim.object_families import pick_set_weights as pick_set_weights_of
from hingelab.sim.objects import ObjectSpec
from hingelab.sim.randomization import RandomizationConfig
from hingelab.tasks import MAX_SPEED, TARGET_HEIGHT, TOOL_PICK_ID, Z_SCALE, task_spaces

OBJECT_NOISE_M = 0.002


class ToolPickEnv(SimRenderMixin, gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}
    env_name = "ToolPick-v0"  # in the error messages

    def __init__(self, object: str = "sphere", size: float = 0.02, mass: float = 0.01,
                 low_level: str = "privileged", randomize: bool = True, placement_half_width: float = 0.05,
                 max_episode_steps: int = 200, encoder_path: str | None = None,
                 reward: HighLevelRewardConfig | None = None, render_mode: str | None = None,
                 terminate_on_drop: bool = True, observe_extent: bool = False, perception: str = "synthesized",
                 object_perception: str = TRUTH, object_noise: str = GAUSSIAN, object_noise_model: str | None = None,
                 pick_set_weights: dict | None = None, tool_position: str = OBSERVED, hand_eye: str = CALIBRATED):
        self.tool_position = check_tool_position(tool_position, f"{self.env_name} tool_position")
        self.hand_eye = hand_eye
        # a family draws a new object at each reset (the model is rebuilt for it); until then its seed-0 draw
        self.object_family = ObjectFamily.parse(object, size) if is_family(object) else None
        if pick_set_weights is not None:  # more of the sets a policy misses (its failures' share of training)
            self.object_family = replace(self.object_family, set_weights=pick_set_weights_of(
                pick_set_weights, self.object_family, f"{self.env_name} pick_set_weights"))
        self.object = self.object_family.draw(0) if self.object_family else ObjectSpec(object, size, mass)
        self.object_record: dict | None = self.object.record if self.object_family else None
        if max_episode_steps < 1:
            raise ConfigError(f"max_episode_steps must be positive, not {max_episode_steps}")
        self.object_perception = check_object_perception_with(object_perception, perception)
        self.sim = SimCore("tool_pick", obj=self.object, randomization=RandomizationConfig(enabled=randomize),
                           camera=camera_for(perception))
        self.perception = ToolPerception(load_encoder(encoder_path), dt=self.sim.control_dt, perception=perception,
                                         hand_eye=hand_eye)
        self.object_camera = None if object_perception == TRUTH else CameraObjectEstimate(object_perception)
        if fitted_estimator(object_noise) is not None and self.object_camera is not None:
            raise ConfigError(f"object noise {object_noise!r} draws the camera's error without rendering; object "
                              f"perception {object_perception!r} renders it: choose one")
        self.object_fitted = make_fitted(object_noise, object_noise_model)
        self.object_noise = object_noise
        calibration = self.perception.calibration
        if calibration is None:
            raise ConfigError("the encoder checkpoint has no latent-opening calibration; retrain it")
        if low_level == "privileged":
            self.low_level = PrivilegedLowLevel(calibration)
        else:
            checkpoint = SHIPPED_LOW_LEVEL if low_level == "policy" else low_level
            self.low_level = PolicyLowLevel(checkpoint, encoder=self.perception.encoder)
        if isinstance(reward, dict):  # as a run's config records it (JSON)
            reward = HighLevelRewardConfig(**reward)
        self.reward_config = reward or HighLevelRewardConfig()
        # the one success verdict (is_success, the episode's success): the object within the radius of the target
        self.success_verdict = f"object_within_{100 * self.reward_config.success_radius:g}cm"
        self.placement_half_width = placement_half_width
        self.max_episode_steps = max_episode_steps
        self.terminate_on_drop = terminate_on_drop
        self.render_mode = render_mode
        self.observe_extent = bool(observe_extent)
        self.observation_space, self.action_space = task_spaces(TOOL_PICK_ID, self.observe_extent)
        self._cache_object_geometry()
        self.delay = DelayLine(self.sim.control_dt, 0.150)
        self._privileged_command = None
        self.steps = 0
        self.last_record: dict = {}

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        episode_seed = int(self.np_random.integers(2**31))
        if self.object_family is not None:  # this episode's object, from its reset seed (else the derived one)
            self._use_object(self.object_family.draw(episode_seed if seed is None else seed))
        center = scripted.platform_center(self.sim.model)
        xy = center + self.np_random.uniform(-self.placement_half_width, self.placement_half_width, 2)
        if options and "object_xy" in options:
            xy = np.asarray(options["object_xy"], float)
        self.state = self.sim.reset(seed=episode_seed, object_xy=xy)
        self.perception.reset(episode_seed)
        if self.object_camera is not None:
            self.object_camera.new_episode(episode_seed, self.sim.model)
        if self.object_fitted is not None:
            self.object_fitted.new_episode(episode_seed, self.object.shape, self.object.size)
        self.low_level.reset()
        self.object_start = self.state.object_pos_world.copy()
        self.tool_start = self.state.tool_pos_hand.copy()
        self.target = self.object_start + [0.0, 0.0, TARGET_HEIGHT]
        self.steps, self.attempt, self.held, self.first_attempt_success = 0, 1, False, False
        self._privileged_command = None
        self.sample = self.perception.observe(self.sim)
        self._observe_object()
        self.tool_pose = ObservedToolPose(self.tool_position, self.perception.tool_state.prior)
        self.tool_pose.reset(self.sample.rotation[0], self.sample.position[0], self.sample.euler_xyz[0])
        self.z_goal = self.sample.z_smoothed[0].copy()
        self.delay.reset(self._fresh_observation())
        info = self._info(self._terms(), False)
        self.last_record = self._record(None, info)
        return self._observation(), info

    def command_privileged(self, arm_velocity_world: np.ndarray, hinge_target: float | None,
                           hand_targets: np.ndarray) -> None:
        """Let the next ``step`` execute a privileged command (the heuristic) instead of its action.

        The step then reports, in ``info["executed_action"]``, the high-level action the
        paper records for it: the latent reached as z_goal and the commanded velocity.
        """
        self._privileged_command = (np.asarray(arm_velocity_world, float), hinge_target,
                                    np.asarray(hand_targets, float))

    def step(self, action):
        action = np.asarray(action, dtype=float)
        if action.shape != self.action_space.shape or not np.isfinite(action).all():
            raise ConfigError(f"{self.env_name} takes {self.action_space.shape[0]} finite values in [-1, 1], "
                              f"got {action!r}")
        # a view into MjData: the privileged branch reads it after the step, the policy branch before
        rot_hand = self.sim.data.xmat[self._hand_body].reshape(3, 3)
        if self._privileged_command is not None:
            velocity_world, hinge_target, hand_targets = self._privileged_command
            self._privileged_command = None
            self.sim.set_hand_targets(hand_targets)
            result = self.sim.step(arm_velocity=velocity_world, hinge_target=hinge_target)
            velocity_hand = rot_hand.T @ velocity_world
            executed = None  # filled below, once the reached latent is known
        else:
            action = np.clip(action, -1, 1)
            command, velocity_hand = self._finger_action(action)
            result = self.sim.step(arm_velocity=rot_hand @ velocity_hand, **command)
            executed = action
        self.steps += 1
        self.state = result.state
        self.sample = self.perception.observe(self.sim)
        self._observe_object()
        self.tool_pose.update(self.sample.rotation[0], self.sample.position[0], self.sample.euler_xyz[0])
        if executed is None:  # paper: the current latent stands for the previous step's z_goal
            self.z_goal = self.sample.z_smoothed[0].copy()
            executed = np.clip(np.concatenate([self.z_goal / Z_SCALE, velocity_hand / MAX_SPEED]), -1, 1)
        self.delay.push(self._fresh_observation())
        terms = self._terms()
        success = bool(np.linalg.norm(self.state.object_pos_world - self.target) < self.reward_config.success_radius)
        self._count_attempts(success)
        info = self._info(terms, success)
        info["executed_action"] = np.asarray(executed, float)
        dropped = info["tool_dropped"] and not success and not result.diverged
        terminated = success or (dropped and self.terminate_on_drop)
        blind = self.perception.flag is not None  # the camera gave no cloud: end the episode, keep what it did
        info["perception_flag"] = self.perception.flag
        unseen = False  # the camera has never estimated the object: nothing to reach for
        if self.object_camera is not None:
            unseen = self.object_camera.estimate is None
            info["object_perception_flag"] = self.object_camera.flag
        truncated = (not terminated) and (result.diverged or blind or unseen
                                          or self.steps >= self.max_episode_steps)
        if result.diverged:
            info["failure_reason"] = "divergence"
        elif blind and not terminated:
            info["failure_reason"] = "no_camera_cloud"
        elif unseen and not terminated:
            info["failure_reason"] = "no_object_estimate"
        elif dropped:
            info["failure_reason"] = "tool_drop"
        elif truncated:
            info["failure_reason"] = "drop" if self.attempt > 1 else "timeout"
        self.last_record = self._record(executed, info)
        return self._observation(), float(sum(terms.values())), terminated, truncated, info

    def _camera(self):
        return self.object_start, 0.5, 135, -25

    # ------------------------------------------------------------------ the object
    def _cache_object_geometry(self) -> None:
        """Ids and the object's geoms with their bounding boxes' corners in the geom frames, for the model."""
        self._object_body = self.sim.reader.object_body
        self._hand_body = self.sim.reader.hand_body  # hand_base's body id (by-name access costs ~1 us a call)
        model = self.sim.model
        self._object_geoms = np.flatnonzero(model.geom_bodyid == self._object_body)  # a mesh's convex parts
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
        self._object_corners = model.geom_aabb[self._object_geoms, None, :3] + \
            signs * model.geom_aabb[self._object_geoms, None, 3:]  # (geoms, 8, 3)
        if getattr(self.object, "pieces", None):  # a drawn mesh (family:picksets draws primitives)
            # a drawn piece's box sits in MuJoCo's mesh frame (its principal axes), turned against the world's
            # under a yaw: its vertices instead (repeated up to the longest piece's count), for the exact box
            meshes = model.geom_dataid[self._object_geoms]
            count = int(model.mesh_vertnum[meshes].max())
            self._object_corners = np.stack([model.mesh_vert[a + np.minimum(np.arange(count), n - 1)]
                                             for a, n in zip(model.mesh_vertadr[meshes], model.mesh_vertnum[meshes])])

    def _use_object(self, obj) -> None:
        """Make ``obj`` (a family's draw) the object: the model rebuilt, and what held the old one refreshed."""
        self.object_record = obj.record
        if obj == self.object:
            return
        self.object = obj
        self.sim.set_object(obj)
        self._cache_object_geometry()
        self.perception.close()  # the camera's renderer held the old model; the next frame makes a new one
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # ------------------------------------------------------------------ parts
    def _finger_action(self, action: np.ndarray) -> tuple[dict, np.ndarray]:
        """The clipped action -> (the finger command, ``sim.step``'s keywords; the hand-frame velocity, m/s).

        Here the low level turns the latent goal into finger motion; ToolPickFlat-v0 (the flat
        baseline) overrides this to move the fingers by the action itself.
        """
        self.z_goal = action[:2] * Z_SCALE
        velocity_hand = action[2:] * MAX_SPEED
        return self.low_level.act(self.sim, self.z_goal, self._low_level_observation()), velocity_hand

    def _to_hand(self, p_world: np.ndarray) -> np.ndarray:
        """World point (m) -> hand_base frame (m)."""
        d = self.sim.data
        return d.xmat[self._hand_body].reshape(3, 3).T @ (p_world - d.xpos[self._hand_body])

    def _fresh_observation(self) -> np.ndarray:
        # the truth's noise is drawn with an estimate too, so all start each step from the same stream
        centre_noise = self.np_random.normal(0.0, OBJECT_NOISE_M, 3)
        estimate = self.object_camera if self.object_camera is not None else self.object_fitted
        centre = self.observed_object_centre() + centre_noise if estimate is None else estimate.centre
        parts = [self.tool_pose.observation(), self.sample.z_smoothed[0], self._to_hand(centre),
                 self._to_hand(self.target)]
        if self.observe_extent:
            extent_noise = self.np_random.normal(0.0, OBJECT_NOISE_M, 3)
            box = None if estimate is None else estimate.box  # a model without an extent fit: the Gaussian
            parts.append(self.observed_object_extent() + extent_noise if box is None else box)
        return np.concatenate(parts)

    def _observe_object(self) -> None:
        """The camera's object estimate on this step's frame (``object_perception`` an estimator), or drawn from the
        fitted model (``object_noise``)."""
        if self.object_fitted is not None:
            self.object_fitted.observe(self.observed_object_centre(), self.observed_object_extent())
        if self.object_camera is not None:
            d = self.sim.data
            self.object_camera.observe(self.perception.camera, d.xmat[self._hand_body].reshape(3, 3),
                                       d.xpos[self._hand_body])

    def object_estimate_record(self) -> dict | None:
        """This step's camera estimate of the object beside the truth, in hand_base (m), for the episode; None
        with ``object_perception="truth"`` and ``object_noise="gaussian"``; a fitted model's draw has no points."""
        camera = self.object_camera if self.object_camera is not None else self.object_fitted
        if camera is None:
            return None
        if camera is self.object_fitted:
            box = camera.box
            return {"estimator": self.object_noise, "position": self._to_hand(camera.centre),
                    "extent": np.full(3, np.nan) if box is None else box.copy(), "n_points": 0,
                    "fresh": camera.fresh, "flag": camera.flag or "",
                    "true_position": self._to_hand(self.observed_object_centre()), "points": None}
        d = self.sim.data
        rotation, origin = d.xmat[self._hand_body].reshape(3, 3), d.xpos[self._hand_body]
        points = None if camera.points is None else ((camera.points - origin) @ rotation).astype(np.float32)
        return {"estimator": camera.estimator, "position": self._to_hand(camera.centre),
                "extent": camera.box.copy(), "n_points": camera.n_points, "fresh": camera.fresh,
                "flag": camera.flag or "", "true_position": self._to_hand(self.observed_object_centre()),
                "points": points}

    def observed_object_extent(self) -> np.ndarray:
        """The object's bounding box along the world axes (x, y, z; m), as a camera's detection gives it."""
        data = self.sim.data
        rotations = data.geom_xmat[self._object_geoms].reshape(-1, 3, 3)
        corners = data.geom_xpos[self._object_geoms, None] + np.einsum("gij,gkj->gki", rotations, self._object_corners)
        corners = corners.reshape(-1, 3)
        return corners.max(axis=0) - corners.min(axis=0)

    def observed_object_centre(self) -> np.ndarray:
        """The object's centre (world, m) as a camera would report it: the middle of its resting height,
        not its body origin (a tetrahedron's origin is on its base face, at the platform)."""
        lift = self.object.centre_height
        if lift == 0.0:  # sphere, cube, cylinder, meshes: the origin is the centre
            return self.state.object_pos_world
        up = self.sim.data.xmat[self._object_body].reshape(3, 3)[:, 2]  # the body's z axis in the world
        return self.state.object_pos_world + up * lift

    def _observation(self) -> np.ndarray:
        delay = self.sim.episode.observation_delay_s if self.sim.episode else 0.0
        return self.delay.read(delay)

    def _low_level_observation(self) -> np.ndarray:
        q, qdot = self.sim.hand_observation()
        s = self.sample
        return np.concatenate([q, qdot, s.velocity_smoothed[0], s.angular_velocity_smoothed[0], s.z_smoothed[0]])

    def _terms(self) -> dict[str, float]:
        return high_level_terms(scripted.grip_point(self.sim), self.state.object_pos_world, self.target,
                                self.state.table_collision, self.reward_config)

    def _count_attempts(self, success: bool) -> None:
        """A grasp holds the object off the platform; losing it without success ends an attempt."""
        lifted = self.state.object_pos_world[2] > self.object_start[2] + 0.005
        holding = self.state.tool_object_contacts >= 2 and lifted
        if holding:
            self.held = True
        elif self.held and not lifted and not success:
            self.held = False
            self.attempt += 1
        if success and self.attempt == 1:
            self.first_attempt_success = True

    def _info(self, terms: dict, success: bool) -> dict:
        drift = float(np.linalg.norm(self.state.tool_pos_hand - self.tool_start))
        return {
            "is_success": float(success),
            "reward_terms": terms,
            "attempt": self.attempt,
            "first_attempt_success": float(self.first_attempt_success),
            "object_target_distance": float(np.linalg.norm(self.state.object_pos_world - self.target)),
            "table_collision": bool(self.state.table_collision),
            "hinge_angle": self.state.hinge_angle,
            "tool_drift_m": drift,
            "tool_dropped": drift > DROP_DISTANCE_M,
            "z_goal": self.z_goal.copy(),
        }

    def _record(self, action, info: dict) -> dict:
        s = self.sample
        return {
            "cloud": self.perception.cloud, "tool_rotation": s.rotation[0], "tool_position": s.position[0],
            "latent_z": s.z[0], "latent_z_smoothed": s.z_smoothed[0], "goal_z": self.z_goal.copy(),
            "action": None if action is None else np.asarray(action, float), "reward_terms": info["reward_terms"],
            "privileged": self.state, "object_position_hand": self._to_hand(self.state.object_pos_world),
            "target_position_hand": self._to_hand(self.target), "object_estimate": self.object_estimate_record(),
            "platform_hand": scripted.platform_in_hand(self.sim.model, self.sim.data, self._hand_body),
        }

"""The baselines: hand-written policies that every learned policy is measured against.

High level (ToolPick-v0; episode policies: each reads the simulator through the env it acts in):
``heuristic`` (the privileged heuristic commanding the arm and the hinge directly), ``scripted`` (its
arm motion and hinge command as the 5-D action over the low level: the demonstrator the phase clone
copies), ``scripted-observed`` (``scripted`` reading the object's position from the policy's
observation), ``scripted-perceived`` (``scripted-observed`` reading its own grip point and opening from the
observation too: the demonstrator on exactly what the high level observes), ``scripted-feedback``
(``scripted`` without the object's size), ``random`` (uniform actions in [-1, 1], seeded per episode).

Low level (ToolShape-v0; ``Policy``s): ``hold-still`` (zero finger changes) and ``synergy`` (the
calibrated opening through the grasp synergy, with integral feedback on the latent).

Each registers under its name (``hingelab.policies.loading``): ``load_policy("scripted")``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from hingelab.heuristic.controller import HeuristicConfig, PrivilegedHeuristic
from hingelab.heuristic.feedback import FeedbackHeuristic
from hingelab.perception.grip_point import grip_points_world
from hingelab.policies.loading import register_baseline
from hingelab.policies.phase_clone import phase_index
from hingelab.sim.finger_synergy import FingerSynergy
from hingelab.tasks import MAX_SPEED, OBSERVED_OBJECT, OBSERVED_TOOL_POSE, OBSERVED_TOOL_POSITION, OBSERVED_Z, Z_SCALE

# ------------------------------------------------------------------ high level (ToolPick-v0)
BASELINES = ("heuristic", "scripted", "scripted-observed", "scripted-perceived", "scripted-feedback", "random")


# ------------------------------------------------------------------ policies
class RandomPolicy:
    """Uniform random actions in [-1, 1]^5, seeded per episode."""

    def reset(self, env, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def act(self, env, obs) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, 5).astype(np.float32)


class HeuristicPolicy:
    """The privileged heuristic: each step commands the arm and the hinge directly (``command_privileged``)."""

    privileged = True
    heuristic_config: dict = {}  # HeuristicConfig fields set otherwise than the heuristic's own

    def reset(self, env, seed: int) -> None:
        pick = env.unwrapped
        self.heuristic = PrivilegedHeuristic(pick.sim, FingerSynergy.load(), pick.object,
                                             HeuristicConfig(**self.heuristic_config))
        self.heuristic.reset(pick.state, pick.target)

    def act(self, env, obs) -> np.ndarray:
        pick = env.unwrapped
        command = self.heuristic.act(pick.state)
        pick.command_privileged(command.arm_velocity, command.hinge_target, command.hand_targets)
        return np.zeros(5, np.float32)


class ScriptedPolicy(HeuristicPolicy):
    """The heuristic's arm motion and hinge command as ToolPick-v0's 5-D action over the low level."""

    privileged = False
    # Over a low level the hinge follows the command with a lag, and the tool shifts in the hand as the
    # fingers close it (the choices and their measurements: analysis/high-level/README.md):
    # - close_steps: closing longer than the heuristic's 12 steps, so the tips hold before the lift;
    # - max_squeeze_fraction: squeezing past the contact angle by at most half of it, so the tips of a
    #   small object's narrow grip do not close shut and squeeze it out;
    # - close_tracking: the grip point servoed onto the object while closing, since the closing leg
    #   drags it sideways in the hand and one tip would push the object off.
    heuristic_config = {"close_steps": 20, "max_squeeze_fraction": 0.5, "close_tracking": True}
    # Gaussian noise (std, action units) on the executed hand velocity, 0 for none: demos for cloning that
    # show the demonstrator recovering from off-course states (DART, Laskey et al. 2017); its clean action
    # goes into the step's labels (``demo_action_0`` .. ``_4``), which the clone learns instead. Never on
    # the latent goal: noise there makes the low level shake the tool out of the hand.
    action_noise = 0.0

    def reset(self, env, seed: int) -> None:
        super().reset(env, seed)
        self.noise = self.noise_stream(seed)

    @staticmethod
    def noise_stream(seed: int) -> np.random.Generator:
        return np.random.default_rng([seed, 0xDA27])  # apart from the env's own streams

    def act(self, env, obs) -> np.ndarray:
        return self._action(env, env.unwrapped.state)

    def _action(self, env, state) -> np.ndarray:
        pick = env.unwrapped
        heuristic = self.heuristic
        phase, steps = phase_index(heuristic.phase), heuristic.phase_steps
        command = heuristic.act(state)
        # the demonstrator's memory around this decision: what the phase clone learns to keep itself
        self.labels = {"demo_phase": phase, "demo_phase_steps": steps, "demo_next_phase": phase_index(heuristic.phase)}
        opening = command.hinge_target if command.hinge_target is not None else state.hinge_angle
        z_goal = np.asarray(pick.perception.calibration.z_for_opening(opening), float)
        rot_hand = pick.sim.data.xmat[pick.sim.reader.hand_body].reshape(3, 3)
        velocity_hand = rot_hand.T @ np.asarray(command.arm_velocity, float)
        action = np.clip(np.concatenate([z_goal / Z_SCALE, velocity_hand / MAX_SPEED]), -1, 1).astype(np.float32)
        if not self.action_noise:
            return action
        self.labels.update({f"demo_action_{i}": float(a) for i, a in enumerate(action)})
        noisy = action.copy()
        noisy[2:] += self.noise.normal(0.0, self.action_noise, 3)  # the hand velocity (ToolPick-v0's last 3)
        return np.clip(noisy, -1, 1).astype(np.float32)


class ObservedScriptedPolicy(ScriptedPolicy):
    """``ScriptedPolicy`` told where the object is by the policy's own observation (its 2 mm noise and
    the observation delay, the hand-frame centre mapped back through the hand's pose) instead of by
    the simulator, every step: how far the scripted motion gets on what a Markov high level can know
    of the object's position. (The reset's start position, used only to notice drops, stays true.)"""

    def act(self, env, obs) -> np.ndarray:
        return self._action(env, self.observed_state(env, obs))

    @staticmethod
    def observed_state(env, obs):
        """The env's privileged state with the object's position replaced by the observation's."""
        pick = env.unwrapped
        data, hand = pick.sim.data, pick.sim.reader.hand_body
        centre = data.xmat[hand].reshape(3, 3) @ np.asarray(obs[OBSERVED_OBJECT], float) + data.xpos[hand]
        origin = centre - (pick.observed_object_centre() - pick.state.object_pos_world)  # centre -> body origin
        return replace(pick.state, object_pos_world=origin)


class PerceivedScriptedPolicy(ObservedScriptedPolicy):
    """``ObservedScriptedPolicy`` that also knows its own tweezer only as the policy does: the grip point rebuilt
    from the observed tool pose and the opening read off the observed z_bar (``hingelab.perception.grip_point``),
    that opening as the hinge angle, all mapped through the hand's current pose. The demonstrator on exactly the
    high level's observation (its tool-pose error, the anchored or tracked position, the delay): how many picks
    that observation allows a demonstrator, against the privileged one's and a clone's."""

    def act(self, env, obs) -> np.ndarray:
        pick = env.unwrapped
        obs = np.asarray(obs, float)
        data, hand = pick.sim.data, pick.sim.reader.hand_body
        hand_rot, hand_pos = data.xmat[hand].reshape(1, 3, 3), data.xpos[hand].reshape(1, 3)
        z_bar = obs[OBSERVED_Z].reshape(1, 2)
        tool_rot = pick.tool_pose.rotation(obs[OBSERVED_TOOL_POSE]).reshape(1, 3, 3)  # in the env's form
        grip, _, _ = grip_points_world(obs[OBSERVED_TOOL_POSITION].reshape(1, 3), tool_rot, z_bar, hand_rot, hand_pos,
                                       pick.perception.calibration)
        self.heuristic.grip_point = lambda: grip[0]
        opening = float(np.asarray(pick.perception.calibration.opening_rad(z_bar)).reshape(-1)[0])
        return self._action(env, replace(self.observed_state(env, obs), hinge_angle=opening))


class FeedbackScriptedPolicy(ScriptedPolicy):
    """``ScriptedPolicy`` of the size-free heuristic (``hingelab.heuristic.feedback``): one opening width,
    the observed centre as the grip height, the hinge closed by feedback on the perceived opening."""

    def reset(self, env, seed: int) -> None:
        pick = env.unwrapped

        def perceived_opening() -> float:
            return float(pick.perception.calibration.opening_rad(pick.sample.z_smoothed[0]))

        self.heuristic = FeedbackHeuristic(pick.sim, FingerSynergy.load(), pick.object, perceived_opening)
        self.heuristic.reset(pick.state, pick.target)
        self.noise = self.noise_stream(seed)


# ------------------------------------------------------------------ low level (ToolShape-v0)
class HoldStillPolicy:
    """The do-nothing baseline: zero finger changes. It "succeeds" whenever the goal happens to
    lie near the opening the hand holds at rest, so a learned policy must beat its rate."""

    hingelab_provenance = {"policy": "hold still (zero action)"}

    def predict(self, obs, deterministic: bool = True):
        return np.zeros(9, dtype=np.float32), None


class SynergyPolicy:
    """The scripted reference: z_goal -> opening (the encoder's calibration) -> the grasp
    synergy's finger targets, approached at the action limit, with integral feedback on
    the latent: the commanded opening moves by ``feedback`` times the latent error along
    the calibration axis (converted to rad by the curve's mean slope) every step, which
    removes the offset between the calibration and the in-hand latent and the gain and
    friction randomization. ``feedback=0``: open loop. It sees only what a policy sees
    (the goal latent, z_bar, the delayed hand q), so its success rate is what a
    hand-written controller reaches through the same perception; its episodes make
    demonstration datasets for ``hingelab train low --from``."""

    hingelab_provenance = {"policy": "scripted synergy (calibrated opening -> finger targets, latent feedback)"}

    def __init__(self, calibration, action_scale: float = 0.05, squeeze: float = 0.03, feedback: float = 0.2):
        self.calibration, self.action_scale, self.squeeze = calibration, action_scale, squeeze
        self.synergy = FingerSynergy.load()
        self.feedback = feedback
        low, high = self.synergy.theta_range
        self.bounds = (max(low, 0.0) - 0.05, high + 0.05)  # room past the table for the integral to act
        span = np.diff(calibration.coordinate(calibration.z_for_opening(np.array([low, high]))))[0]
        self.per_rad = float(span / (high - low))  # latent coordinate per rad of opening
        self.command = None

    def reset(self) -> None:
        self.command = None

    def predict(self, obs, deterministic: bool = True):
        goal = np.asarray(obs["desired_goal"], float)
        if self.command is None:
            # goals are points of the calibration curve: their own opening (as the demonstrations were made)
            self.command = float(self.calibration.project_opening(goal))
        error = float(self.calibration.coordinate(goal) - self.calibration.coordinate(obs["achieved_goal"]))
        self.command = float(np.clip(self.command + self.feedback * error / self.per_rad, *self.bounds))
        targets = self.synergy.targets(self.command - self.squeeze)
        q = np.asarray(obs["observation"], float)[:9]
        return np.clip((targets - q) / self.action_scale, -1, 1).astype(np.float32), None


def _synergy(env=None):
    if env is None:
        raise ValueError("the synergy baseline needs the ToolShape-v0 env it acts in: load_policy('synergy', env=env)")
    unwrapped = env.unwrapped
    return SynergyPolicy(unwrapped.calibration, action_scale=unwrapped.action_scale)


for _name, _cls, _text in (
        ("heuristic", HeuristicPolicy, "the privileged heuristic, commanding the hinge directly"),
        ("scripted", ScriptedPolicy, "the heuristic's arm motion and hinge command as the high level's action"),
        ("scripted-observed", ObservedScriptedPolicy, "scripted, the object's position from the observation"),
        ("scripted-perceived", PerceivedScriptedPolicy,
         "scripted-observed, its grip point and opening from the observation too"),
        ("scripted-feedback", FeedbackScriptedPolicy, "scripted without the object's size"),
        ("random", RandomPolicy, "uniform random actions")):
    register_baseline(_name, "high", lambda env=None, _cls=_cls: _cls(), _text)
register_baseline("hold-still", "low", lambda env=None: HoldStillPolicy(), "zero finger changes")
register_baseline("synergy", "low", _synergy, "the calibrated opening through the grasp synergy, latent feedback")

__all__ = ["RandomPolicy", "HeuristicPolicy", "ScriptedPolicy", "ObservedScriptedPolicy", "PerceivedScriptedPolicy",
           "FeedbackScriptedPolicy",
           "HoldStillPolicy", "SynergyPolicy"]

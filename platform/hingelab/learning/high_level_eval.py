"""Evaluating a high-level policy (or a baseline) on ``hingelab/ToolPick-v0``: ``hingelab eval high``.

Every episode is an MCAP episode (``RecordingWrapper``, source ``high_level_evaluation``);
its ``success`` is the env's one verdict (object within 1 cm of the target, ``info["is_success"]``
at the last step), ``first_attempt_success`` and ``attempt`` are the env's (``_count_attempts``).

Seeds (paired): episode i of ``--seed K`` is reset with ``episode_seed(K, i) = SEED_BASE + K *
SEED_STRIDE + i`` (SEED_BASE = 900_000_000, SEED_STRIDE = 100_003), the same for every baseline
and checkpoint, so their episodes start from the same object placement, randomization and
noise. (``hingelab generate heuristic`` uses ``K * 100_003 + i``: the evaluation seeds are other ones.)
The random baseline draws its actions from ``numpy.random.default_rng(episode seed)``.

Failure reasons (``FailureReasonWrapper``, recorded as the episode's ``failure_reason``): the env
gives ``divergence``, ``no_camera_cloud`` (camera perception: a frame gave no tool cloud), ``tool_drop``, and at the time limit ``drop`` (a grasp held and was lost,
attempt > 1) or ``timeout``. From what the episode did (privileged state, every step) they become,
first match wins: ``divergence``; ``no_camera_cloud``; ``tool_drop``; ``slip`` (the env's ``drop``: the object was held
off the platform and lost); ``table_collision`` (the hand or tool touched the table during the
episode); ``missed_grasp`` (the object was never held, though the tweezer's grip point came within
2 cm of it); ``timeout`` (anything else: never got near, or held but not brought to the target).
The env's own reason stays in ``episodes.csv`` as ``env_failure_reason``.

Baselines: ``heuristic`` (the privileged heuristic, ``hingelab.heuristic``: hinge commanded
directly through ``command_privileged``); ``scripted`` (the heuristic's arm motion, closing for 20
steps instead of its 12, squeezing at most half the contact angle and keeping the grip point on the
object while closing (``ScriptedPolicy.heuristic_config``), its hinge command turned into a latent goal, ``calibration.z_for_opening(opening) / Z_SCALE`` clipped to
[-1, 1], and its world velocity into the hand frame / MAX_SPEED, acting through the env's normal
5-D action over the low level); ``scripted-observed`` (``scripted`` reading the object's position from
the policy's observation, noise and delay included, instead of the simulator); ``scripted-feedback`` (the same without the object's size:
``hingelab.heuristic.feedback``); ``random`` (uniform actions in [-1, 1]).
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd

from hingelab.analysis.pick_table import FAILURE_REASONS, pick_rates

SEED_BASE = 900_000_000
SEED_STRIDE = 100_003
BASELINES = ("heuristic", "scripted", "scripted-observed", "scripted-feedback", "random")
MISSED_GRASP_DISTANCE_M = 0.02


def episode_seed(seed: int, index: int) -> int:
    """The reset seed of episode ``index`` of an evaluation with ``--seed seed`` (paired across policies)."""
    return SEED_BASE + int(seed) * SEED_STRIDE + int(index)


class FailureReasonWrapper(gym.Wrapper):
    """Refines ToolPick-v0's ``failure_reason`` at the episode's end (module doc); under the recorder."""

    def reset(self, **kwargs):
        self.held_ever, self.collided, self.closest = False, False, np.inf
        return self.env.reset(**kwargs)

    def step(self, action):
        from hingelab.sim import scripted

        obs, reward, terminated, truncated, info = self.env.step(action)
        pick = self.env.unwrapped
        self.held_ever |= bool(pick.held)
        self.collided |= bool(info.get("table_collision", False))
        grip = scripted.grip_point(pick.sim)
        self.closest = min(self.closest, float(np.linalg.norm(grip - pick.state.object_pos_world)))
        if (terminated or truncated) and not info.get("is_success", 0.0):
            info = dict(info)
            info["env_failure_reason"] = info.get("failure_reason", "timeout")
            info["failure_reason"] = self.classify(info["env_failure_reason"])
        return obs, reward, terminated, truncated, info

    def classify(self, env_reason: str) -> str:
        if env_reason in ("divergence", "no_camera_cloud", "tool_drop"):
            return env_reason
        if env_reason == "drop":
            return "slip"
        if self.collided:
            return "table_collision"
        if not self.held_ever and self.closest < MISSED_GRASP_DISTANCE_M:
            return "missed_grasp"
        return "timeout"


def make_eval_env(object: str, size: float, low_level: str, record_dir: Path | None = None,
                  extra_metadata: dict | None = None, max_episode_steps: int = 200, observe_extent: bool = False,
                  perception: str = "synthesized"):
    """ToolPick-v0 (randomized as in training), failure reasons refined, recorded into ``record_dir``;
    ``observe_extent`` as the policy was trained (its checkpoint's ``env_kwargs``); ``perception``:
    synthesized clouds or the depth camera."""
    from hingelab.envs import TOOL_PICK_ID
    from hingelab.envs.recording import RecordingWrapper
    from hingelab.sim.mesh_objects import object_label

    env = FailureReasonWrapper(gym.make(TOOL_PICK_ID, object=object, size=size, low_level=low_level,
                                        max_episode_steps=max_episode_steps, observe_extent=observe_extent,
                                        perception=perception))
    if record_dir is not None:
        env = RecordingWrapper(env, record_dir, source="high_level_evaluation", object_name=object_label(object),
                               action_level="high", extra_metadata={"object_size": size, **(extra_metadata or {})})
    return env


# ------------------------------------------------------------------ policies
class RandomPolicy:
    """Uniform random actions in [-1, 1]^5, seeded per episode."""

    def reset(self, env, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def act(self, env, obs) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, 5).astype(np.float32)


class ModelPolicy:
    """A stable-baselines3 model or a ``PhaseClone`` (deterministic actions); a policy with memory gets
    its state back each step and a fresh one each episode, as SB3's recurrent policies do."""

    def __init__(self, model):
        self.model = model
        self.state = None

    def reset(self, env, seed: int) -> None:
        self.state = None  # None: the episode's start (SAC ignores it, the phase clone starts in "open")

    def act(self, env, obs) -> np.ndarray:
        action, self.state = self.model.predict(obs, state=self.state, deterministic=True)
        return np.asarray(action, np.float32)


class HeuristicPolicy:
    """The privileged heuristic: each step commands the arm and the hinge directly (``command_privileged``)."""

    privileged = True
    heuristic_config: dict = {}  # HeuristicConfig fields set otherwise than the heuristic's own

    def reset(self, env, seed: int) -> None:
        from hingelab.heuristic.controller import HeuristicConfig, PrivilegedHeuristic
        from hingelab.sim.finger_synergy import FingerSynergy

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
    # fingers close it (chosen on eval high --seed 6000 and 6100; analysis/high-level/README.md):
    # - close_steps: the heuristic's 12 steps lifted the 2.5 cm sphere before the tips held it (seed
    #   6000, 30 episodes: 0.87 with 12, 0.97 with 20); since 2026-12-05, before 12;
    # - max_squeeze_fraction: the full 0.05 rad squeeze past the 1.5 cm tetrahedron's 0.042 rad contact
    #   closed the tips shut and squeezed it out (seed 6100, 30 episodes: 0.60, with half of the
    #   contact angle as squeeze at most 0.97); since 2026-12-05 (later);
    # - close_tracking: standing still while closing, the closing leg dragged the grip point 2-3 mm
    #   sideways and one tip pushed the 2.5 cm sphere off (seed 6100: 0.83, tracking 1.00); since 2026-12-05 (later).
    heuristic_config = {"close_steps": 20, "max_squeeze_fraction": 0.5, "close_tracking": True}
    # Gaussian noise (std, action units) on the executed hand velocity, 0 for none: demos for cloning that
    # show the demonstrator recovering from off-course states (DART, Laskey et al. 2017); its clean action
    # goes into the step's labels (``demo_action_0`` .. ``_4``), which the clone learns instead. Not on the
    # latent goal: the low level shakes the tool out of the hand (0.1 on all five: 18 of the last 20 demos
    # of the 1.5 cm sphere dropped the tool, 1 of the first 26 of the 2 cm sphere picked it)
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
        from hingelab.envs.tool_pick import MAX_SPEED, Z_SCALE
        from hingelab.learning.phase_clone import phase_index

        pick = env.unwrapped
        heuristic = self.heuristic
        phase, steps = phase_index(heuristic.phase), heuristic.phase_steps
        command = heuristic.act(state)
        # the demonstrator's memory around this decision: what the phase clone learns to keep itself
        self.labels = {"demo_phase": phase, "demo_phase_steps": steps, "demo_next_phase": phase_index(heuristic.phase)}
        opening = command.hinge_target if command.hinge_target is not None else pick.state.hinge_angle
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


class DemonstratorLabels(gym.Wrapper):
    """Puts the driving policy's ``labels`` of the step (``ScriptedPolicy``: the demonstrator's phase
    before and after its decision) into the step's info, which ``RecordingWrapper`` records."""

    def __init__(self, env, policy):
        super().__init__(env)
        self.policy = policy

    def step(self, action):
        labels = getattr(self.policy, "labels", None)
        obs, reward, terminated, truncated, info = self.env.step(action)
        if labels:
            info = {**info, **labels}
        return obs, reward, terminated, truncated, info


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
        from dataclasses import replace

        from hingelab.envs.tool_pick import OBSERVED_OBJECT

        pick = env.unwrapped
        data, hand = pick.sim.data, pick.sim.reader.hand_body
        centre = data.xmat[hand].reshape(3, 3) @ np.asarray(obs[OBSERVED_OBJECT], float) + data.xpos[hand]
        origin = centre - (pick.observed_object_centre() - pick.state.object_pos_world)  # centre -> body origin
        return replace(pick.state, object_pos_world=origin)


class FeedbackScriptedPolicy(ScriptedPolicy):
    """``ScriptedPolicy`` of the size-free heuristic (``hingelab.heuristic.feedback``): one opening width,
    the observed centre as the grip height, the hinge closed by feedback on the perceived opening."""

    def reset(self, env, seed: int) -> None:
        from hingelab.heuristic.feedback import FeedbackHeuristic
        from hingelab.sim.finger_synergy import FingerSynergy

        pick = env.unwrapped

        def perceived_opening() -> float:
            return float(pick.perception.calibration.opening_rad(pick.sample.z_smoothed[0]))

        self.heuristic = FeedbackHeuristic(pick.sim, FingerSynergy.load(), pick.object, perceived_opening)
        self.heuristic.reset(pick.state, pick.target)
        self.noise = self.noise_stream(seed)


def baseline_policy(name: str):
    policies = {"heuristic": HeuristicPolicy, "scripted": ScriptedPolicy, "scripted-observed": ObservedScriptedPolicy,
                "scripted-feedback": FeedbackScriptedPolicy, "random": RandomPolicy}
    if name not in policies:
        raise ValueError(f"unknown baseline {name!r}; choose one of {BASELINES}")
    return policies[name]()


# ------------------------------------------------------------------ rollouts
def run_episode(policy, env, seed: int) -> dict:
    """One episode from reset seed ``seed``; a row of the episode table."""
    obs, info = env.reset(seed=seed)
    policy.reset(env, seed)
    total, length = 0.0, 0
    while True:
        obs, reward, terminated, truncated, info = env.step(policy.act(env, obs))
        total += float(reward)
        length += 1
        if terminated or truncated:
            break
    success = bool(info.get("is_success", 0.0))
    return {"seed": seed, "success": success, "first_attempt_success": bool(info.get("first_attempt_success", 0.0)),
            "attempts": int(info.get("attempt", 1)), "failure_reason": "" if success else info["failure_reason"],
            "env_failure_reason": "" if success else info.get("env_failure_reason", ""), "length": length,
            "return": total, "object_target_distance_m": float(info["object_target_distance"])}


def evaluate(policy, env, episodes: int, seed: int, progress: bool = False, label: str = "eval high",
             journal=None) -> pd.DataFrame:
    """``episodes`` episodes, episode i from ``episode_seed(seed, i)``; one row each. ``journal`` (an
    ``eval_journal.EpisodeJournal``): its rows are kept and their episodes not run again; each new row
    goes into it as its episode finishes."""
    from tqdm import tqdm

    rows = list(journal.rows) if journal is not None else []
    done = {int(r["episode"]) for r in rows}
    with tqdm(range(episodes), desc=label, unit="episode", disable=not progress, initial=0) as bar:
        for i in bar:
            if i in done:
                continue
            if hasattr(env, "extra_metadata"):
                env.extra_metadata = {**env.extra_metadata, "episode_index": str(i)}
            row = {"episode": i, **run_episode(policy, env, episode_seed(seed, i))}
            if journal is not None:
                journal.append(row)
            rows.append(row)
            bar.set_postfix(success=f"{sum(r['success'] for r in rows) / len(rows):.2f}")
    return pd.DataFrame(rows).sort_values("episode", ignore_index=True)


def success_table(episodes: pd.DataFrame, object: str, size: float) -> pd.DataFrame:
    """One row per shape and size: success (the env's verdict) and first-attempt success with Wilson 95%
    intervals, mean attempts, and the count of each failure reason (``pick_rates``)."""
    return pd.DataFrame([{"object": object, "size_cm": round(100 * size, 3), **pick_rates(episodes)}])


__all__ = ["BASELINES", "FAILURE_REASONS", "SEED_BASE", "SEED_STRIDE", "FailureReasonWrapper", "FeedbackScriptedPolicy",
           "HeuristicPolicy", "ModelPolicy", "ObservedScriptedPolicy", "RandomPolicy", "ScriptedPolicy", "baseline_policy", "episode_seed",
           "evaluate", "make_eval_env", "run_episode", "success_table"]

"""Evaluating a high-level policy (or a baseline) on ``hingelab/ToolPick-v0``: ``hingelab eval high``.

Every episode is an MCAP episode (``RecordingWrapper``, source ``high_level_evaluation``);
its ``success`` is the env's one verdict (object within 1 cm of the target, ``info["is_success"]``
at the last step), ``first_attempt_success`` and ``attempt`` are the env's (``_count_attempts``).

Seeds (paired): episode i of ``--seed K`` is reset with ``hingelab.seeds.eval_high_seed(K, i)``, the same
for every baseline
and checkpoint, so their episodes start from the same object placement, randomization and
noise (``hingelab generate heuristic``'s demos are another stream of the plan).
The random baseline draws its actions from ``numpy.random.default_rng(episode seed)``.

Failure reasons (``FailureReasonWrapper``, recorded as the episode's ``failure_reason``): the env
gives ``divergence``, ``no_camera_cloud`` (camera perception: a frame gave no tool cloud), ``no_object_estimate`` (a
camera object estimator: no frame has estimated the object yet), ``tool_drop``, and at the
time limit ``drop`` (a grasp held and was lost, attempt > 1) or ``timeout``. From what the episode did (privileged
state, every step) they become, first match wins: ``divergence``; ``no_camera_cloud``; ``no_object_estimate``;
``tool_drop``; ``slip`` (the
env's ``drop``: the object was held off the platform and lost); ``table_collision`` (the hand or tool touched the table
during the episode); ``missed_grasp`` (the object was never held, though the tweezer's grip point came within
2 cm of it); ``timeout`` (anything else: never got near, or held but not brought to the target).
The env's own reason stays in ``episodes.csv`` as ``env_failure_reason``.

Baselines: ``heuristic`` (the privileged heuristic, ``hingelab.heuristic``: hinge commanded
directly through ``command_privileged``); ``scripted`` (the heuristic's arm motion, closing for 20
steps instead of its 12, squeezing at most half the contact angle and keeping the grip point on the
object while closing (``ScriptedPolicy.heuristic_config``), its hinge command turned into a latent goal,
``calibration.z_for_opening(opening) / Z_SCALE`` clipped to [-1, 1], and its world velocity into the hand frame /
MAX_SPEED, acting through the env's normal 5-D action over the low level); ``scripted-observed`` (``scripted`` reading
the object's position from the policy's observation, noise and delay included, instead of the simulator);
``scripted-feedback`` (the same without the object's size: ``hingelab.heuristic.feedback``); ``random`` (uniform actions
in [-1, 1]).
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pandas as pd
from tqdm import tqdm

from hingelab.analysis.pick_table import FAILURE_REASONS, pick_rates
from hingelab.envs import TOOL_PICK_ID
from hingelab.envs.recording import RecordingWrapper
from hingelab.seeds import EVAL_HIGH_BASE, STRIDE, eval_high_seed
from hingelab.sim import scripted
from hingelab.sim.mesh_objects import object_label

SEED_BASE, SEED_STRIDE = EVAL_HIGH_BASE, STRIDE  # what the evaluations' cards quote
MISSED_GRASP_DISTANCE_M = 0.02




class FailureReasonWrapper(gym.Wrapper):
    """Refines ToolPick-v0's ``failure_reason`` at the episode's end (module doc); under the recorder."""

    def reset(self, **kwargs):
        self.held_ever, self.collided, self.closest = False, False, np.inf
        return self.env.reset(**kwargs)

    def step(self, action):

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
        if env_reason in ("divergence", "no_camera_cloud", "no_object_estimate", "tool_drop"):
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
                  perception: str = "synthesized", object_perception: str = "truth", object_noise: str = "gaussian",
                  object_noise_model: str | None = None, tool_position: str = "observed"):
    """ToolPick-v0 (randomized as in training), failure reasons refined, recorded into ``record_dir``;
    ``observe_extent`` as the policy was trained (its checkpoint's ``env_kwargs``); ``perception``:
    synthesized clouds or the depth camera; ``object_perception``: the object's true centre with 2 mm noise, or a
    camera object estimator (``hingelab.perception.object_perception``); ``object_noise``: ``"fitted:NAME"`` for the
    camera's error drawn from a fitted model (``hingelab.perception.object_noise_model``); ``tool_position``:
    ToolPick-v0's "observed" or "anchored" tool position."""

    env = FailureReasonWrapper(gym.make(TOOL_PICK_ID, object=object, size=size, low_level=low_level,
                                        max_episode_steps=max_episode_steps, observe_extent=observe_extent,
                                        perception=perception, object_perception=object_perception,
                                        object_noise=object_noise, object_noise_model=object_noise_model,
                                        tool_position=tool_position))
    if record_dir is not None:
        env = RecordingWrapper(env, record_dir, source="high_level_evaluation", object_name=object_label(object),
                               action_level="high", extra_metadata={"object_size": size, **(extra_metadata or {})})
    return env


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
             journal=None, indices=None) -> pd.DataFrame:
    """``episodes`` episodes, episode i from ``eval_high_seed(seed, i)``; one row each. ``journal`` (an
    ``eval_journal.EpisodeJournal``): its rows are kept and their episodes not run again; each new row
    goes into it as its episode finishes. ``indices``: only these of the ``episodes`` (a worker's share of
    them; the rows are the same as in a run of all of them)."""

    rows = list(journal.rows) if journal is not None else []
    done = {int(r["episode"]) for r in rows}
    order = range(episodes) if indices is None else [int(i) for i in indices]
    with tqdm(order, desc=label, unit="episode", disable=not progress, initial=0) as bar:
        for i in bar:
            if i in done:
                continue
            if hasattr(env, "extra_metadata"):
                env.extra_metadata = {**env.extra_metadata, "episode_index": str(i)}
            row = {"episode": i, **run_episode(policy, env, eval_high_seed(seed, i))}
            if journal is not None:
                journal.append(row)
            rows.append(row)
            bar.set_postfix(success=f"{sum(r['success'] for r in rows) / len(rows):.2f}")
    return pd.DataFrame(rows).sort_values("episode", ignore_index=True)


def success_table(episodes: pd.DataFrame, object: str, size: float) -> pd.DataFrame:
    """One row per shape and size: success (the env's verdict) and first-attempt success with Wilson 95%
    intervals, mean attempts, and the count of each failure reason (``pick_rates``)."""
    return pd.DataFrame([{"object": object, "size_cm": round(100 * size, 3), **pick_rates(episodes)}])


__all__ = ["FAILURE_REASONS", "SEED_BASE", "SEED_STRIDE", "DemonstratorLabels", "FailureReasonWrapper",
           "evaluate", "make_eval_env", "run_episode", "success_table"]

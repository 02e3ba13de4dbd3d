"""The privileged prior a ``train high`` run generates for itself when no ``--from`` is given.

Two sources of privileged demonstrations, both recorded as ToolPick-v0 high-level episodes
(source ``heuristic``) into ``RUNDIR/prior``:

* ``scripted`` (the default): the privileged heuristic acting through the high level's own
  action over the run's low level: its arm motion as the hand velocity, its hinge command
  turned into a latent goal through the encoder's calibration (``eval high --baseline
  scripted``). The demo action is the recorded command (``demo_actions="recorded"``).
* ``heuristic``: ``hingelab generate heuristic``: the heuristic commands the hinge directly
  (privileged low level); the demo action is the latent the tool reached (the paper's,
  ``demo_actions="reached"``).

Why the default is not the paper's: the reached latent of a closed grasp is the latent of the
object's width, which the privileged hinge servo holds with a built-in squeeze
(``FINGER_SQUEEZE``) but a learned low level only reaches without pressing. Behaviour cloning of
100 heuristic sphere episodes (20,000 updates) picked 1 of 10 over the shipped low-level policy
with the reached latent 5 steps on (8 missed grasps), and 0 of 10 with the step's own; the same
cloning of 100 scripted episodes (their commands) picked 9 of 10 (``issues`` note of issue 26).

Seeds: episode i of a prior for run seed S is ``high_level_eval.episode_seed(PRIOR_SEED_BASE + S, i)``
(scripted) or ``generate heuristic``'s ``(PRIOR_SEED_BASE + S) * 100_003 + i`` (heuristic).
"""

from __future__ import annotations

import shutil
from pathlib import Path

PRIOR_SEED_BASE = 700_000
PRIOR_SOURCES = ("scripted", "heuristic")


def generate_prior(root: Path, config, name: str, progress: bool = True) -> Path:
    """Write ``config.prior_episodes`` privileged episodes of ``config.prior_source`` into ``root``."""
    root = Path(root)
    shutil.rmtree(root, ignore_errors=True)  # a generation cut short is made again
    seed = PRIOR_SEED_BASE + config.seed
    if config.prior_source == "heuristic":
        from hingelab.heuristic.rollout import HeuristicRunConfig, generate_heuristic_dataset

        generate_heuristic_dataset(root, HeuristicRunConfig(
            episodes=config.prior_episodes, object=config.object, size=config.size, mass=config.mass, seed=seed,
            randomize=config.randomize, max_episode_steps=config.max_episode_steps), progress=progress, name=name)
        return root
    import gymnasium as gym

    from hingelab.episodes import create_dataset
    from hingelab.envs.recording import RecordingWrapper
    from hingelab.learning.high_level_eval import FailureReasonWrapper, ScriptedPolicy, evaluate
    from hingelab.sim.mesh_objects import object_label

    arguments = config.env_arguments()
    create_dataset(root, name=name, source="heuristic", seed=seed,
                   config={"policy": "scripted", "episodes": config.prior_episodes, **arguments},
                   description="the privileged heuristic's arm motion and hinge command as high-level actions over "
                               f"the low level {config.low_level} (hingelab train high's prior)")
    env = FailureReasonWrapper(gym.make(config.env_id, **arguments))
    env = RecordingWrapper(env, root, source="heuristic", object_name=object_label(config.object), action_level="high",
                           extra_metadata={"object_size": config.size, "policy": "scripted",
                                           "low_level": config.low_level})
    try:
        evaluate(ScriptedPolicy(), env, config.prior_episodes, seed, progress=progress, label="prior (scripted)")
    finally:
        env.close()
    return root


__all__ = ["generate_prior", "PRIOR_SEED_BASE", "PRIOR_SOURCES"]

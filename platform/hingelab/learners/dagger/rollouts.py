"""A DAgger round's rollouts: the clone acts, the scripted demonstrator labels every step it reaches.

``ShadowedClone`` is an episode policy (``reset(env, seed)``, ``act(env, obs)``) that runs the scripted
demonstrator (``eval high --baseline scripted``) beside the clone on the same privileged state every step and
says what it would command there. Its phase is set to the clone's memory before each decision (``sync_phase``):
left to run its own phase machine along the clone's course it falls out of step with it (on the 1.5 cm
tetrahedron it was still descending while the clone had closed and lifted, and then reopened to start again
while the clone carried the object to the target), and its labels would then tell the clone to undo what it did
right. In step, the label answers the question the clone's net is asked: in this state, with this memory, what
would the demonstrator command and where would its phase go next (the prior's demos record the same relation).
The step's labels (``DemonstratorLabels`` puts them in the info, the recorder records them) are the clone's own
memory before the step as ``demo_phase`` / ``demo_phase_steps`` (what the clone reads at run time, so the fit
learns to act from its own memory), the demonstrator's next phase as ``demo_next_phase`` and its action as
``demo_action_0`` .. ``_4``: the labels ``PhaseDemos.from_transitions`` reads, as the prior's demos have them.
With ``demonstrator_share`` > 0 the demonstrator's action is executed instead of the clone's on that share of
the steps (DAgger's beta mixture; ``dagger_executed_demonstrator`` says which).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import gymnasium as gym
import numpy as np

from hingelab.envs.recording import RecordingWrapper
from hingelab.episodes import create_dataset
from hingelab.policies.baselines import ScriptedPolicy
from hingelab.policies.phase_clone import PHASES, phase_index
from hingelab.rollouts.high_level import DemonstratorLabels, FailureReasonWrapper, evaluate
from hingelab.seeds import dagger_block
from hingelab.sim.mesh_objects import object_label
from hingelab.training.prior import pick_set_parts


class ShadowedClone:
    """The clone acting with the scripted demonstrator labelling (module doc)."""

    def __init__(self, clone, demonstrator_share: float = 0.0):
        self.clone, self.demonstrator_share = clone, float(demonstrator_share)
        self.demonstrator = ScriptedPolicy()
        self.labels: dict = {}

    def reset(self, env, seed: int) -> None:
        self.demonstrator.reset(env, seed)
        self.memory = None  # the clone's: None starts it in "open"
        self.rng = np.random.default_rng([seed, 0xDA66E2])  # apart from the env's and the demonstrator's streams

    def act(self, env, obs) -> np.ndarray:
        before = np.zeros(2, np.int64) if self.memory is None else np.asarray(self.memory, np.int64).reshape(2)
        sync_phase(self.demonstrator.heuristic, int(before[0]), int(before[1]), env.unwrapped.state.hinge_angle)
        demonstrated = self.demonstrator.act(env, obs)
        action, self.memory = self.clone.predict(obs, state=self.memory)
        executes_demonstrator = self.demonstrator_share > 0 and self.rng.random() < self.demonstrator_share
        self.labels = {"demo_phase": int(before[0]), "demo_phase_steps": int(before[1]),
                       "demo_next_phase": self.demonstrator.labels["demo_next_phase"],
                       **{f"demo_action_{i}": float(a) for i, a in enumerate(demonstrated)},
                       "dagger_executed_demonstrator": float(executes_demonstrator)}
        return demonstrated if executes_demonstrator else np.asarray(action, np.float32)


def sync_phase(heuristic, phase: int, steps: int, hinge_angle: float) -> None:
    """Put the heuristic (``hingelab.heuristic.controller.PrivilegedHeuristic``) in ``PHASES[phase]`` with ``steps``
    spent there, as the clone's memory says. On a change of phase its hinge command is what entering that phase
    leaves it at: the open width before and in the approach, the hinge's angle on entering the close (its ramp
    starts there), the squeezed contact angle once carrying. (Its "hold", carrying at the target, counts as
    carrying, as in ``PHASES``.)"""
    name = PHASES[phase]
    if phase_index(heuristic.phase) != phase:
        heuristic.phase = name
        if name == "close":
            heuristic.hinge_cmd = float(hinge_angle)
        elif name == "carry":
            heuristic.hinge_cmd = heuristic.contact_theta - heuristic.squeeze
        else:
            heuristic.hinge_cmd = heuristic.open_theta
    heuristic.phase_steps = int(steps)


def rollout_parts(config) -> list[tuple[str, str, float, int]]:
    """(sub-folder, object, size, episodes) of each dataset of a round: the run's object, or the pick table's 12
    sets with the episodes shared evenly."""
    if config.rollout_objects == "run":
        return [("", config.object, config.size, config.dagger_episodes)]
    return [part for part in pick_set_parts(config.dagger_episodes) if part[3] > 0]


def generate_round(root: Path, config, clone, round_index: int, name: str, progress: bool = True) -> list[Path]:
    """Record round ``round_index``'s rollouts of ``clone`` under ``root`` (made again from scratch: a round cut
    short is not kept); the datasets written. Episode i of part k is ``eval high``'s episode i of seed
    ``dagger_block(run seed, round, k)``."""
    root = Path(root)
    shutil.rmtree(root, ignore_errors=True)
    roots = []
    for part, (folder, object, size, episodes) in enumerate(rollout_parts(config)):
        seed = dagger_block(config.seed, round_index, part)
        arguments = {**config.env_arguments(), "object": object, "size": size}
        dataset = root / folder
        create_dataset(dataset, name=name, source=config.train_source, seed=seed,
                       config={"policy": "dagger (the clone acting, the scripted demonstrator labelling)",
                               "round": round_index, "episodes": episodes,
                               "demonstrator_share": config.demonstrator_share, **arguments},
                       description=f"DAgger round {round_index}: the phase clone's rollouts labelled by the scripted "
                                   f"demonstrator over the low level {config.low_level} (hingelab train high "
                                   "--learner dagger)")
        driver = ShadowedClone(clone, config.demonstrator_share)
        env = DemonstratorLabels(FailureReasonWrapper(gym.make(config.env_id, **arguments)), driver)
        env = RecordingWrapper(env, dataset, source=config.train_source, object_name=object_label(object),
                               action_level="high", extra_metadata={"object_size": size, "policy": "dagger",
                                                                    "low_level": config.low_level})
        try:
            evaluate(driver, env, episodes, seed, progress=progress,
                     label=f"round {round_index} ({object_label(object)} {100 * size:g} cm)")
        finally:
            env.close()
        roots.append(dataset)
    return roots


__all__ = ["ShadowedClone", "sync_phase", "rollout_parts", "generate_round"]

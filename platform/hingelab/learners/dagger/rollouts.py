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
from tqdm import tqdm

from hingelab.envs.recording import RecordingWrapper
from hingelab.episodes import create_dataset
from hingelab.policies.baselines import ScriptedPolicy
from hingelab.policies.phase_clone import PHASES, PhaseClone, net_from_state, net_state, phase_index
from hingelab.rollouts.high_level import DemonstratorLabels, FailureReasonWrapper, evaluate
from hingelab.seeds import dagger_block
from hingelab.sim.mesh_objects import object_label
from hingelab.training.prior import pick_set_parts, work_items


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


def generate_round(root: Path, config, clone, round_index: int, name: str, progress: bool = True,
                   pool=None) -> list[Path]:
    """Record round ``round_index``'s rollouts of ``clone`` under ``root`` (made again from scratch: a round cut
    short is not kept); the datasets written. Episode i of part k is ``eval high``'s episode i of seed
    ``dagger_block(run seed, round, k)``. ``pool`` (a ``hingelab.workers.job_pool.JobPool``): the episodes
    recorded in its workers, shared as the prior's are (``hingelab.training.prior.work_items``): the same
    episodes and labels into the same datasets."""
    root = Path(root)
    shutil.rmtree(root, ignore_errors=True)
    parts = []
    for part, (folder, object, size, episodes) in enumerate(rollout_parts(config)):
        dataset = root / folder
        parts.append({"dataset": str(dataset), "config": config, "round": round_index, "object": object,
                      "size": size, "episodes": episodes, "seed": dagger_block(config.seed, round_index, part)})
    if pool is None:
        for part in parts:
            _round_dataset(part, name)
            _record_part(part, clone, progress=progress)
        return [Path(part["dataset"]) for part in parts]
    for part in parts:
        _round_dataset(part, name)
    nets = [net_state(net) for net in clone.nets]
    items = [{**parts[k], "nets": nets, "indices": indices}
             for k, indices in work_items([part["episodes"] for part in parts], pool.jobs)]
    with tqdm(total=len(items), desc=f"round {round_index}", unit="part", disable=not progress) as bar:
        pool.map(_record_item, items, done=lambda *_: bar.update())
    return [Path(part["dataset"]) for part in parts]


def _round_dataset(part: dict, name: str) -> None:
    """The card of one dataset of a round."""
    config, round_index = part["config"], part["round"]
    arguments = {**config.env_arguments(), "object": part["object"], "size": part["size"]}
    create_dataset(part["dataset"], name=name, source=config.train_source, seed=part["seed"],
                   config={"policy": "dagger (the clone acting, the scripted demonstrator labelling)",
                           "round": round_index, "episodes": part["episodes"],
                           "demonstrator_share": config.demonstrator_share, **arguments},
                   description=f"DAgger round {round_index}: the phase clone's rollouts labelled by the scripted "
                               f"demonstrator over the low level {config.low_level} (hingelab train high "
                               "--learner dagger)")


def _record_item(item: dict) -> None:
    """A ``--jobs`` worker's share of a round's dataset (``generate_round``)."""
    clone = PhaseClone([net_from_state(state) for state in item["nets"]])
    _record_part(item, clone, progress=False, indices=item["indices"])


def _record_part(part: dict, clone, progress: bool, indices=None) -> None:
    """The clone's rollouts, labelled (``ShadowedClone``), recorded into one dataset of a round: its episodes, or
    ``indices`` of them."""
    config, object, size = part["config"], part["object"], part["size"]
    arguments = {**config.env_arguments(), "object": object, "size": size}
    driver = ShadowedClone(clone, config.demonstrator_share)
    env = DemonstratorLabels(FailureReasonWrapper(gym.make(config.env_id, **arguments)), driver)
    env = RecordingWrapper(env, part["dataset"], source=config.train_source, object_name=object_label(object),
                           action_level="high", extra_metadata={"object_size": size, "policy": "dagger",
                                                                "low_level": config.low_level})
    try:
        evaluate(driver, env, part["episodes"], part["seed"], progress=progress, indices=indices,
                 label=f"round {part['round']} ({object_label(object)} {100 * size:g} cm)")
    finally:
        env.close()


__all__ = ["ShadowedClone", "sync_phase", "rollout_parts", "generate_round"]

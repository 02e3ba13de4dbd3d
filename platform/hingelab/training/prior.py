"""The privileged prior a ``train high`` run generates for itself when no ``--from`` is given.

Three sources of privileged demonstrations, all recorded as ToolPick-v0 high-level episodes
(source ``heuristic``) into ``RUNDIR/prior``:

* ``scripted`` (the default): the privileged heuristic acting through the high level's own
  action over the run's low level: its arm motion as the hand velocity, its hinge command
  turned into a latent goal through the encoder's calibration (``eval high --baseline
  scripted``). The demo action is the recorded command (``demo_actions="recorded"``).
* ``scripted-feedback``: as ``scripted``, without the object's size (``hingelab.heuristic.feedback``:
  one opening width, the hinge closed by feedback on the perceived opening), so that its actions
  follow from what the high level observes on every shape and size (``--prior-objects all``).
* ``heuristic``: ``hingelab generate heuristic``: the heuristic commands the hinge directly
  (privileged low level); the demo action is the latent the tool reached (the paper's,
  ``demo_actions="reached"``).

With ``--prior-action-noise STD`` (scripted sources), the executed hand velocity carries Gaussian
noise and each step's info records the demonstrator's clean action (``demo_action_0`` .. ``_4``), which
the phase clone learns: the demos visit states off the demonstrator's course and show it recovering.

Why the default is not the paper's: the reached latent of a closed grasp is the latent of the
object's width, which the privileged hinge servo holds with a built-in squeeze
(``FINGER_SQUEEZE``) but a learned low level only reaches without pressing: a policy cloned from the
heuristic's reached latents misses its grasps over the learned low level, one cloned from the scripted
demonstrator's commands picks (the runs: ``analysis/high-level/README.md``).

Seeds: episode i of the k-th dataset (``prior_parts``) of a prior for run seed S is
``hingelab.seeds.eval_high_seed(K, i)`` (scripted, scripted-feedback) or ``demo_seed(K, i)`` (heuristic), with
K = ``hingelab.seeds.prior_block(S, k)``.
"""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import gymnasium as gym
from tqdm import tqdm

from hingelab.envs.recording import RecordingWrapper
from hingelab.episodes import create_dataset
from hingelab.policies import load_policy
from hingelab.rollouts.heuristic_demos import HeuristicRunConfig, generate_heuristic_dataset
from hingelab.rollouts.high_level import DemonstratorLabels, FailureReasonWrapper, evaluate
from hingelab.seeds import prior_block
from hingelab.sim.mesh_objects import object_label
from hingelab.sim.objects import PICK_SETS  # noqa: F401  (the pick table's sets: --prior-objects all)
from hingelab.training.config_parts import PRIOR_OBJECTS, PRIOR_SOURCES
from hingelab.workers.job_pool import chunks


def pick_set_parts(episodes: int) -> list[tuple[str, str, float, int]]:
    """(sub-folder, shape, size, episodes) for each of the pick table's 12 sets, ``episodes`` shared evenly (the
    first sets get one more where it does not divide)."""
    share, extra = divmod(episodes, len(PICK_SETS))
    return [(f"{shape}_{100 * size:g}cm", shape, size, share + (i < extra))
            for i, (shape, size) in enumerate(PICK_SETS)]


def prior_parts(config) -> list[tuple[str, object, float, int]]:
    """(sub-folder, object, size, episodes) of each dataset of the run's prior: one folder, ``""``, for
    ``--prior-objects run``; one per pick-table set for ``all`` (``pick_set_parts``)."""
    if config.prior_objects == "run":
        return [("", config.object, config.size, config.prior_episodes)]
    return pick_set_parts(config.prior_episodes)


def generate_prior(root: Path, config, name: str, progress: bool = True, pool=None) -> list[Path]:
    """Write ``config.prior_episodes`` privileged episodes of ``config.prior_source`` under ``root``;
    the datasets written (``prior_parts``). ``pool`` (a ``hingelab.workers.job_pool.JobPool``; scripted
    sources): the episodes recorded in its workers (``work_items``), the same episodes into the same datasets."""
    root = Path(root)
    shutil.rmtree(root, ignore_errors=True)  # a generation cut short is made again
    parts = []
    for index, (folder, object, size, episodes) in enumerate(prior_parts(config)):
        # the sets' seeds are apart (their episodes would otherwise share placements and noise)
        seed = prior_block(config.seed, index)
        parts.append((root / folder, replace(config, object=object, size=size, prior_episodes=episodes,
                                              prior_objects="run"), seed))
    if pool is None or config.prior_source == "heuristic":
        return [_generate(folder, part, seed, name, progress) for folder, part, seed in parts]
    for folder, part, seed in parts:
        _scripted_dataset(folder, part, seed, name)
    items = [{"root": str(parts[k][0]), "config": parts[k][1], "seed": parts[k][2], "indices": indices}
             for k, indices in work_items([part.prior_episodes for _, part, _ in parts], pool.jobs)]
    with tqdm(total=len(items), desc="prior", unit="part", disable=not progress) as bar:
        pool.map(_record_item, items, done=lambda *_: bar.update())
    return [folder for folder, _, _ in parts]


def work_items(episodes: list[int], jobs: int) -> list[tuple[int, range | None]]:
    """How ``jobs`` processes share the datasets of ``episodes`` episodes each: (dataset, None: all its episodes)
    when there are as many datasets as processes or more, so each dataset is recorded by one process, one
    episode after another, its files as one process writes them; else each dataset's episodes cut into ``jobs``
    contiguous blocks (dataset, range), written side by side into it (the same episodes, their files named in
    the order they were written)."""
    if len(episodes) >= jobs:
        return [(k, None) for k in range(len(episodes))]
    return [(k, block) for k, n in enumerate(episodes) for block in chunks(n, jobs)]


def _generate(root: Path, config, seed: int, name: str, progress: bool) -> Path:
    if config.prior_source == "heuristic":

        generate_heuristic_dataset(root, HeuristicRunConfig(
            episodes=config.prior_episodes, object=config.object, size=config.size, mass=config.mass, seed=seed,
            randomize=config.randomize, max_episode_steps=config.max_episode_steps), progress=progress, name=name)
        return root
    _scripted_dataset(root, config, seed, name)
    _record(root, config, seed, progress)
    return root


def _scripted_dataset(root: Path, config, seed: int, name: str) -> None:
    """The card of a scripted prior dataset."""
    policy = config.prior_source  # scripted or scripted-feedback: eval high's baselines
    create_dataset(root, name=name, source="heuristic", seed=seed,
                   config={"policy": policy, "episodes": config.prior_episodes,
                           "action_noise": config.prior_action_noise, **config.env_arguments()},
                   description=f"the privileged heuristic ({policy}) as high-level actions over "
                               f"the low level {config.low_level} (hingelab train high's prior)")


def _record_item(item: dict) -> None:
    """A ``--jobs`` worker's share of a prior dataset (``generate_prior``)."""
    _record(Path(item["root"]), item["config"], item["seed"], progress=False, indices=item["indices"])


def _record(root: Path, config, seed: int, progress: bool, indices=None) -> None:
    """The scripted demonstrator's episodes (``indices`` of them, default all) recorded into the dataset ``root``."""
    arguments = config.env_arguments()
    policy = config.prior_source
    demonstrator = load_policy(policy)
    demonstrator.action_noise = config.prior_action_noise
    # the demonstrator's phases go into every step's info (the phase clone learns them)
    env = DemonstratorLabels(FailureReasonWrapper(gym.make(config.env_id, **arguments)), demonstrator)
    env = RecordingWrapper(env, root, source="heuristic", object_name=object_label(config.object), action_level="high",
                           extra_metadata={"object_size": config.size, "policy": policy,
                                           "low_level": config.low_level})
    try:
        evaluate(demonstrator, env, config.prior_episodes, seed, progress=progress, indices=indices,
                 label=f"prior ({policy}, {object_label(config.object)} {100 * config.size:g} cm)")
    finally:
        env.close()


__all__ = ["PICK_SETS", "PRIOR_OBJECTS", "PRIOR_SOURCES", "generate_prior", "pick_set_parts",
           "prior_parts", "work_items"]

"""The seed plan: every stream of episode seeds the platform resets its envs with, in one place.

A command's ``--seed S`` picks a block of a stream; episode ``k`` of the block gets its own reset seed,
so an episode is the same wherever and in whatever order it runs (workers, Ray, a resume).

=====================  ===========================================  =================================
stream                 episode k of seed S                          used by
=====================  ===========================================  =================================
demos                  S * STRIDE + k                               generate heuristic, the camera gap
trials                 TRIALS_BASE + S * STRIDE + k                 hingelab trial
high-level evaluation  EVAL_HIGH_BASE + S * STRIDE + k              eval high, the pick table, the demo
prior                  the demos' or the high-level evaluation's    train high's generated prior
                       stream at block prior_block(S, part)
training evaluation    the high-level evaluation's block            train high / flat / phase clone
                       TRAINING_EVALUATION_SEED                     (held out during training)
training rollouts      training_episode_seed(S, env, k)             train low / high / flat rollouts
low-level held out     HELD_OUT_BASE + k (fixed goals);             train low's evaluations; eval low
                       HELD_OUT_BASE + SAMPLED_OFFSET + S * 10_007 + k
object draws           a generator from object_draw_entropy(s,      ToolPick-v0 with family:NAME[:SEED]
                       SEED): s the episode's reset seed            objects (sim.object_families)
=====================  ===========================================  =================================

A ``--seed`` is in [0, 2**32) (``SEED_BOUND``; ``seed_argument`` is every command's door): the run seed seeds
NumPy's legacy generator (32 bits), and within it every stream's episode seed keeps below 2**63, so a dataset's
index (int64) holds it.

Within the user-facing domain (``S`` below ``SEED_LIMIT``, ``k`` below ``EPISODE_LIMIT``) the demos,
trials, high-level evaluation, prior and low-level held-out streams are disjoint (``tests/test_seeds.py``).
The training rollouts' stream keeps below the trials, the evaluations and the held-out goals for run seeds
below ``TRAINING_SEED_LIMIT`` with up to 16 envs of ``TRAINING_EPISODE_LIMIT`` episodes each, but it shares
numbers with the demos' stream: a training run's rollouts can start where a ``generate heuristic`` dataset's
demos start (both are training data; no evaluation sees them). It is kept as it is because every trained
checkpoint was made with it: changing it changes what a seed trains.

The object draws are not reset seeds but the entropy of their own generator, ``[OBJECT_DRAW_KEY, SEED or
NO_FAMILY_SEED, s]``: the key lies above every seed of every stream (and above 2**32), so the draw shares no
numbers with the env's own generator (seeded with ``s`` alone) nor with the streams seeded ``[s, k]``.
"""

from __future__ import annotations

import argparse
import random
from contextlib import contextmanager

SEED_BOUND = 2**32  # a --seed is below this (and not negative)
STRIDE = 100_003  # episodes per block (a prime: blocks of neighbouring seeds do not line up)
SEED_LIMIT = 1_000  # the --seed values the plan keeps apart ...
EPISODE_LIMIT = 10_000  # ... for this many episodes per command
TRAINING_SEED_LIMIT = 700  # training run seeds whose rollouts keep below the trials ...
TRAINING_EPISODE_LIMIT = 12_000  # ... with this many episodes per env
TRIALS_BASE = 800_000_000
EVAL_HIGH_BASE = 900_000_000
PRIOR_BASE = 700_000  # the prior's blocks: far above any --seed of generate heuristic
PRIOR_PART_STRIDE = 1_000
TRAINING_EVALUATION_SEED = 77  # train's held-out evaluations: `hingelab eval high --seed 77`'s episodes
HELD_OUT_BASE = 2_000_000_000  # low-level held-out goals, above every training rollout's seed
SAMPLED_OFFSET = 1_000_000  # eval low's sampled goals, apart from train low's fixed ones
SAMPLED_STRIDE = 10_007
MEMBER_STRIDE = 1_000_003
OBJECT_DRAW_KEY = 0x4F424A454354  # "OBJECT": the first word of every object draw's entropy (above 2**32)
NO_FAMILY_SEED = 2**32 - 1  # the family SEED word of family:NAME without one (a SEED is below 2**31)


def seed_argument(text: str) -> int:
    """The argparse ``type`` of every ``--seed``: an integer in [0, ``SEED_BOUND``)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if not 0 <= value < SEED_BOUND:
        raise argparse.ArgumentTypeError(f"{value} is out of range: a seed is in [0, 2**32)")
    return value


def demo_seed(seed: int, index: int) -> int:
    """Episode ``index`` of ``hingelab generate heuristic --seed seed`` (and of a prior's heuristic demos)."""
    return int(seed) * STRIDE + int(index)


def trial_seed(seed: int, index: int) -> int:
    """Trial ``index`` of ``hingelab trial --seed seed``."""
    return TRIALS_BASE + int(seed) * STRIDE + int(index)


def eval_high_seed(seed: int, index: int) -> int:
    """Episode ``index`` of ``hingelab eval high --seed seed``: paired across policies and baselines."""
    return EVAL_HIGH_BASE + int(seed) * STRIDE + int(index)


def prior_block(run_seed: int, part: int) -> int:
    """The block (a ``--seed`` of the demos' stream) of part ``part`` of run ``run_seed``'s generated prior."""
    return PRIOR_BASE + int(run_seed) + PRIOR_PART_STRIDE * int(part)


def dagger_block(run_seed: int, round_index: int, part: int) -> int:
    """The block (a ``--seed`` of ``eval high``'s stream) of part ``part`` of round ``round_index`` of DAgger run
    ``run_seed``'s rollouts: past every prior part's block (``prior_block``: parts below 100)."""
    return PRIOR_BASE + int(run_seed) + PRIOR_PART_STRIDE * (100 * (int(round_index) + 1) + int(part))


def training_episode_seed(run_seed: int, env_index: int, episode: int) -> int:
    """Episode ``episode`` of rollout env ``env_index`` of a training run: determined by the count, so a
    resumed run and 1 or N envs replay the same episodes."""
    return (int(run_seed) * 1_000_003 + int(env_index) * STRIDE + int(episode) * 7919) % HELD_OUT_BASE


def held_out_goal_seed(index: int) -> int:
    """The ``index``-th fixed held-out goal of a low-level run's evaluations."""
    return HELD_OUT_BASE + int(index)


def sampled_goal_seed(seed: int, index: int) -> int:
    """Goal ``index`` of ``hingelab eval low --seed seed``."""
    return HELD_OUT_BASE + SAMPLED_OFFSET + int(seed) * SAMPLED_STRIDE + int(index)


@contextmanager
def preserved_global_rngs():
    """Run the block without advancing Python's, NumPy's or torch's global generators: loading a checkpoint
    builds networks (whose initial weights are drawn, then overwritten) and stable-baselines3 reseeds the
    generators when it sets a model up, and a run that loads one after seeding must train what its seed
    says, whether or not the process loaded it before."""
    import numpy as np  # here, not at the top: the parser's --seed type comes from this module (fast --help)
    import torch  # only the callers that load torch models come here; the seed plan itself is light

    states = random.getstate(), np.random.get_state(), torch.random.get_rng_state()
    try:
        yield
    finally:
        random.setstate(states[0])
        np.random.set_state(states[1])
        torch.random.set_rng_state(states[2])


def object_draw_entropy(episode_seed: int, family_seed: int | None = None) -> list[int]:
    """The entropy (``numpy.random.default_rng(entropy)``) of the generator that draws the object of the
    episode reset with ``episode_seed`` from ``family:NAME[:family_seed]`` (``hingelab.sim.object_families``).
    The key is two 32-bit words and the SEED word one, so two different (SEED, seed) pairs never give one
    entropy (and ``s`` always comes last: numpy's SeedSequence pads short entropy with zeros, so a trailing
    0 word would not count)."""
    return [OBJECT_DRAW_KEY, NO_FAMILY_SEED if family_seed is None else int(family_seed), int(episode_seed)]


def ensemble_member_seed(seed: int, member: int) -> int:
    """The fit seed of member ``member`` of an ensemble fitted with ``seed`` (member 0: ``seed`` itself)."""
    return int(seed) + int(member) * MEMBER_STRIDE


__all__ = ["SEED_BOUND", "seed_argument",
           "STRIDE", "SEED_LIMIT", "EPISODE_LIMIT", "TRAINING_SEED_LIMIT", "TRAINING_EPISODE_LIMIT", "TRIALS_BASE",
           "EVAL_HIGH_BASE", "PRIOR_BASE", "TRAINING_EVALUATION_SEED", "HELD_OUT_BASE", "demo_seed", "trial_seed",
           "eval_high_seed", "prior_block", "dagger_block", "training_episode_seed", "held_out_goal_seed",
           "sampled_goal_seed", "ensemble_member_seed", "OBJECT_DRAW_KEY", "object_draw_entropy"]

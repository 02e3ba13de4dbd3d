"""The seed plan (``hingelab.seeds``): the streams the platform resets its envs from keep apart."""

from __future__ import annotations

import numpy as np

from hingelab import seeds

SEEDS = np.arange(seeds.SEED_LIMIT)
EPISODES = seeds.EPISODE_LIMIT


def test_the_user_facing_streams_never_give_the_same_seed():
    """Each of these streams is base + block * STRIDE + k: two give one seed only where the blocks' difference
    times STRIDE plus the bases' difference is within EPISODE_LIMIT of 0; checked exactly for every pair."""
    users = range(seeds.SEED_LIMIT)
    priors = range(seeds.prior_block(0, 0), seeds.prior_block(seeds.SEED_LIMIT - 1, 11) + 1)  # 12 pick-table parts
    streams = {"demos": (0, users), "trials": (seeds.TRIALS_BASE, users),
               "high-level evaluation": (seeds.EVAL_HIGH_BASE, users),
               "prior, scripted": (seeds.EVAL_HIGH_BASE, priors),
               "prior, heuristic": (0, priors)}
    assert seeds.trial_seed(7, 3) == seeds.TRIALS_BASE + 7 * seeds.STRIDE + 3  # the form the check relies on
    assert seeds.eval_high_seed(7, 3) == seeds.EVAL_HIGH_BASE + 7 * seeds.STRIDE + 3
    assert seeds.demo_seed(7, 3) == 7 * seeds.STRIDE + 3
    names = list(streams)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            (base_a, blocks_a), (base_b, blocks_b) = streams[a], streams[b]
            differences = range(blocks_b.start - (blocks_a.stop - 1), blocks_b.stop - blocks_a.start)
            closest = min(abs(d * seeds.STRIDE + base_b - base_a) for d in differences)
            assert closest >= EPISODES, f"{a} and {b} can give the same seed"
    # the low-level held-out goals lie between the evaluations and the priors
    held_out = (seeds.held_out_goal_seed(0), seeds.sampled_goal_seed(seeds.SEED_LIMIT - 1, EPISODES - 1))
    assert seeds.eval_high_seed(seeds.SEED_LIMIT - 1, EPISODES - 1) < held_out[0]
    assert held_out[1] < seeds.demo_seed(seeds.prior_block(0, 0), 0)


def test_the_prior_blocks_of_different_runs_and_parts_differ():
    blocks = {seeds.prior_block(s, part) for s in range(seeds.PRIOR_PART_STRIDE) for part in range(12)}
    assert len(blocks) == len(range(seeds.PRIOR_PART_STRIDE + 11 * seeds.PRIOR_PART_STRIDE))
    assert min(blocks) > seeds.SEED_LIMIT  # never a block a user's --seed names


def test_training_rollouts_stay_below_the_trials_evaluations_and_held_out_goals():
    top = max(seeds.training_episode_seed(s, env, seeds.TRAINING_EPISODE_LIMIT - 1)
              for s in range(seeds.TRAINING_SEED_LIMIT) for env in range(16))
    assert top < seeds.TRIALS_BASE < seeds.EVAL_HIGH_BASE < seeds.HELD_OUT_BASE
    assert seeds.training_episode_seed(3, 1, 7) == seeds.training_episode_seed(3, 1, 7)


def test_the_training_stream_shares_numbers_with_the_demos_as_documented():
    """Documented, not hidden: a training run's rollouts can start where generate heuristic's demos start."""
    assert seeds.training_episode_seed(0, 0, 0) == seeds.demo_seed(0, 0)


def test_ensemble_members_are_seeded_apart_and_member_0_is_the_fit_seed():
    assert seeds.ensemble_member_seed(5, 0) == 5
    assert len({seeds.ensemble_member_seed(5, m) for m in range(8)}) == 8


def test_loading_checkpoints_draws_nothing_from_the_global_generators():
    """A run seeds the global generators; a checkpoint loaded after that (the encoder, a SAC zip, a phase
    clone) must not move them, or the run trains something else than its seed says the first time a
    process loads that checkpoint (found as train flat's weights differing between a fresh process and a
    second run in it)."""
    import random

    import torch

    from hingelab.perception.encoder import load_encoder
    from hingelab.policies import load_policy
    from hingelab.policies.high_level import SHIPPED_HIGH_LEVEL
    from hingelab.policies.low_level import SHIPPED_LOW_LEVEL_SAC

    def draws(load: bool):
        torch.manual_seed(7)
        np.random.seed(7)
        random.seed(7)
        if load:
            load_encoder()
            load_policy(SHIPPED_LOW_LEVEL_SAC, level="low")
            load_policy(SHIPPED_HIGH_LEVEL, level="high")
        return float(torch.rand(1)), float(np.random.rand()), random.random()

    assert draws(load=True) == draws(load=False)


def test_object_draws_have_their_own_stream():
    """A family's draw for episode seed s is not the env's generator for s (default_rng(s)), nor a stream
    seeded [s, k] (the camera's, the stand-in's, the controller's), and (SEED, s) pairs never share one."""
    assert seeds.OBJECT_DRAW_KEY > 2**32 > seeds.HELD_OUT_BASE + seeds.SAMPLED_OFFSET + SEEDS[-1] * seeds.SAMPLED_STRIDE
    for s in (0, 1, 28, seeds.eval_high_seed(3, 5)):
        draw = np.random.default_rng(seeds.object_draw_entropy(s)).random(4)
        others = [np.random.default_rng(s)] + [np.random.default_rng([s, k]) for k in (28, 31, 37, 0xDA27)]
        assert all(not np.array_equal(draw, other.random(4)) for other in others)
    entropies = [tuple(seeds.object_draw_entropy(s, family)) for s in (0, 1, 2**31 - 1) for family in (None, 0, 1, 7)]
    states = {np.random.SeedSequence(list(e)).generate_state(4).tobytes() for e in entropies}
    assert len(states) == len(entropies)  # no two (SEED, s) pairs share a generator, SEED 0 not "no SEED" either
    assert seeds.object_draw_entropy(5) == seeds.object_draw_entropy(5, None)

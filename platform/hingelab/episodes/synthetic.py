"""Synthetic episodes of the real shapes, for tests, benchmarks and examples.

A tweezer cloud is two 110 mm legs joined at a hinge, 256 points with 3 mm noise,
in hand_base; the hinge angle follows a slow sine. Every topic of the contract is
filled with values of the right shape and units. Deterministic given the seed.
"""

from __future__ import annotations

import numpy as np

from hingelab.episodes.writer import EpisodeWriter

CONTROL_DT_S = 0.05  # 20 Hz
N_POINTS = 256


def tweezer_cloud(rng: np.random.Generator, hinge_angle: float, n_points: int = N_POINTS) -> np.ndarray:
    """(n_points, 3) float32 metres, hand_base: two legs opening by ``hinge_angle`` rad."""
    s = rng.uniform(0.0, 0.110, n_points)
    leg = rng.integers(0, 2, n_points)
    angle = np.where(leg == 0, -0.5, 0.5) * hinge_angle
    points = np.stack([s * np.cos(angle), s * np.sin(angle), rng.uniform(-0.004, 0.004, n_points)], axis=1)
    points += np.array([0.03, 0.0, 0.08]) + rng.normal(0.0, 0.003, points.shape)
    return points.astype(np.float32)


def synthetic_step(rng: np.random.Generator, k: int, n_steps: int, goal_env: bool = False,
                   action_dim: int = 9) -> dict:
    """Keyword arguments of ``EpisodeWriter.write_step`` for step ``k`` (all topics filled)."""
    hinge = 0.175 + 0.15 * np.sin(0.1 * k)
    q = rng.uniform(-1, 1, 9)
    qd = rng.normal(0, 0.1, 9)
    z = rng.normal(0, 1, 2)
    state = np.concatenate([q, qd, rng.normal(0, 0.01, 6), z]).astype(np.float32)  # the 26-D state
    z_goal = rng.normal(0, 1, 2)
    observation = ({"observation": state, "achieved_goal": z.astype(np.float32),
                    "desired_goal": z_goal.astype(np.float32)} if goal_env else state)
    terms = {"goal": float(np.exp(-np.linalg.norm(z - z_goal))), "effort": -0.01 * float(np.linalg.norm(qd))}
    position = rng.normal(0, 0.02, 3) + [0.05, 0.0, 0.1]
    orientation = np.array([0.0, 0.0, np.sin(hinge / 2), np.cos(hinge / 2)])
    return dict(
        points_hand=tweezer_cloud(rng, hinge),
        tool_pose_hand=(position, orientation),
        joint_position=q, joint_velocity=qd,
        latent_z=z, latent_z_smoothed=0.9 * z,
        action=rng.uniform(-0.05, 0.05, action_dim).astype(np.float32),
        goal_z=z_goal,
        reward_terms=terms,
        object_position_hand=rng.normal(0, 0.05, 3), target_position_hand=rng.normal(0, 0.05, 3),
        privileged={"hinge_angle": hinge, "tool_position": position, "tool_orientation": orientation,
                    "tip_a": rng.normal(0, 0.1, 3), "tip_b": rng.normal(0, 0.1, 3),
                    "object_position": rng.normal(0, 0.1, 3), "object_orientation": [0.0, 0.0, 0.0, 1.0],
                    "contact_count": int(rng.integers(0, 20)), "table_collision": bool(k % 7 == 0)},
        transition={"observation": observation,
                    "action": rng.uniform(-0.05, 0.05, action_dim).astype(np.float32),
                    "reward": sum(terms.values()), "terminated": False, "truncated": k == n_steps - 1,
                    "info": {"is_success": float(k == n_steps - 1)}},
    )


def write_synthetic_episode(dataset_dir, seed: int, n_steps: int = 200, goal_env: bool = False,
                            source: str = "synthetic", object: str = "sphere", **writer_kwargs):
    """Write one synthetic episode; returns (final path, list of the step kwargs written)."""
    rng = np.random.default_rng(seed)
    steps = [synthetic_step(rng, k, n_steps, goal_env) for k in range(n_steps)]
    final_observation = steps[-1]["transition"]["observation"]
    with EpisodeWriter(dataset_dir, source=source, task="reach_latent", object=object, seed=seed,
                       action_level="low", **writer_kwargs) as episode:
        for k, step in enumerate(steps):
            episode.write_step(k * CONTROL_DT_S, **step)
        episode.write_final_observation(final_observation)
        episode.set_outcome(success=bool(seed % 2 == 0), failure_reason=None if seed % 2 == 0 else "timeout")
    return episode.path, steps

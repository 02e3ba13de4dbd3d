"""The ``synthetic_clouds`` dataset: tool clouds over the whole hinge range, for the encoder.

Each cloud is the tweezer at a random opening (uniform over the hinge range) in a random
pose in ``hand_base``: the nominal in-hand pose (the grasp keyframe of the ``tool_shape``
scene) turned by up to ``max_angle_deg`` about each axis and shifted by up to
``max_offset_m``, with the paper's encoder augmentation: 20% removal, 5 mm noise, or,
with ``noise_std_max_m`` set, a noise level drawn per cloud uniformly between
``noise_std_m`` and ``noise_std_max_m``. A PointNet's max pool reads the cloud's extremes,
which grow with the noise, so an encoder trained at one noise level reads clouds at
another as a different opening: trained at 5 mm only, it reads the sim's 3 mm clouds as
too closed (``analysis/low-level-ablation/README.md``).

Episode layout (the episode contract, datasets/README.md): ``clouds_per_episode``
clouds per episode file, one per step (log times 50 ms apart, no dynamics implied):

* ``/tool/points``: the cloud, (256, 3) float32, metres, hand_base;
* ``/sim/privileged``: the ground truth: ``hinge_angle`` (rad, the opening),
  ``tool_position`` and ``tool_orientation`` (x, y, z, w): the pose of the cloud's tool
  frame (leg a) in hand_base, which registration should find; ``tip_a``, ``tip_b``: the
  tip sites in hand_base (tip gap in metres = ``|tip_a - tip_b|``).

Every episode is seeded (``seed`` + episode number), so any file can be regenerated.
"""

from __future__ import annotations

import functools
from dataclasses import asdict
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from hingelab.episodes import EpisodeWriter, create_dataset
from hingelab.episodes.dataset import Dataset, open_dataset
from hingelab.episodes.schemas import TOPIC_PRIVILEGED
from hingelab.errors import ConfigError
from hingelab.perception.cloud_dataset_config import CloudDatasetConfig
from hingelab.perception.clouds import CloudRealism, CloudSynthesizer, ToolGeometry, random_rotations
from hingelab.sim.core import SimCore

SOURCE = "synthetic_clouds"
TASK = "tool_clouds"
STEP_S = 0.05  # log-time spacing of the clouds in an episode


@functools.cache
def nominal_tool_pose() -> tuple[np.ndarray, np.ndarray]:
    """The tool pose in hand_base at the ``tool_shape`` scene's grasp keyframe: (R (3, 3), t (3,) m).

    The prior registration starts from when nothing better is known (the tool starts in
    the hand in this grasp).
    """
    state = SimCore("tool_shape").reset(seed=0)
    w, x, y, z = state.tool_quat_hand
    return Rotation.from_quat([x, y, z, w]).as_matrix(), np.array(state.tool_pos_hand, float)


def sample_clouds(rng: np.random.Generator, n: int, geometry: ToolGeometry, realism: CloudRealism,
                  max_angle_rad: float, max_offset_m: float,
                  noise_range_m: tuple[float, float] | None = None) -> dict[str, np.ndarray]:
    """``n`` clouds at uniform openings in random poses around the nominal in-hand pose.

    ``noise_range_m``: draw each cloud's noise level uniformly from it (else the realism's).
    Returns {points (n, 256, 3) float32 hand_base, hinge_angle (n,) rad, rotation (n, 3, 3),
    position (n, 3) m (the tool frame in hand_base), tip_a, tip_b (n, 3) m hand_base,
    noise_std_m (n,)}.
    """
    rot0, pos0 = nominal_tool_pose()
    rot = rot0 @ random_rotations(rng, n, max_angle_rad)
    pos = pos0 + rng.uniform(-max_offset_m, max_offset_m, (n, 3))
    theta = rng.uniform(*geometry.hinge_range, n)
    noise = (np.full(n, realism.noise_std_m) if noise_range_m is None else rng.uniform(*noise_range_m, n))
    synth = CloudSynthesizer(geometry, realism, seed=int(rng.integers(2 ** 63)))  # no per-episode perturbation
    points = synth.from_tool_pose(rot, pos, theta, noise_std_m=noise)
    tip_a, tip_b = geometry.tips_in_tool_frame(theta)
    return {"points": points, "hinge_angle": theta, "rotation": rot, "position": pos, "noise_std_m": noise,
            "tip_a": np.einsum("bij,bj->bi", rot, tip_a) + pos, "tip_b": np.einsum("bij,bj->bi", rot, tip_b) + pos}


def write_cloud_episode(root: Path, config: CloudDatasetConfig, episode: int, geometry: ToolGeometry) -> Path:
    """Write episode number ``episode`` (seeded by config.seed + episode); returns its path."""
    n = min(config.clouds_per_episode, config.n_clouds - episode * config.clouds_per_episode)
    seed = config.seed + episode
    realism = CloudRealism(config.noise_std_m, config.removal_fraction, 0.0, 0.0)
    batch = sample_clouds(np.random.default_rng(seed), n, geometry, realism,
                          np.deg2rad(config.max_angle_deg), config.max_offset_m,
                          None if config.noise_std_max_m is None else config.noise_range_m)
    quat_xyzw = Rotation.from_matrix(batch["rotation"]).as_quat()
    with EpisodeWriter(root, source=SOURCE, task=TASK, seed=seed,
                       extra_metadata={"geometry_hash": geometry.geometry_hash}) as writer:
        for k in range(n):
            writer.write_step(k * STEP_S, points_hand=batch["points"][k], privileged={
                "hinge_angle": float(batch["hinge_angle"][k]), "tool_position": batch["position"][k],
                "tool_orientation": quat_xyzw[k], "tip_a": batch["tip_a"][k], "tip_b": batch["tip_b"][k]})
        writer.set_outcome(success=True)
    return writer.path


def generate_cloud_dataset(root, config: CloudDatasetConfig, progress: bool = True) -> Dataset:
    """Create the dataset at ``root`` and write every episode (see the module docstring)."""
    root = Path(root)
    geometry = ToolGeometry.default()
    card_config = {**asdict(config), "geometry_hash": geometry.geometry_hash,
                   "nominal_tool_pose": [m.tolist() for m in nominal_tool_pose()]}
    create_dataset(root, name=root.name, source=SOURCE, config=card_config, seed=config.seed,
                   description="tweezer point clouds over the hinge range with ground-truth opening and pose "
                               "(hingelab generate clouds)")
    existing = len(list((root / "episodes").glob("*.mcap")))
    if existing:
        raise ConfigError(f"{root} already holds {existing} episodes; write to a new folder (--out)")
    for episode in tqdm(range(config.n_episodes), desc="clouds", unit="episode", disable=not progress):
        write_cloud_episode(root, config, episode, geometry)
    dataset = Dataset(root)
    dataset.build_index(rebuild=True)
    return dataset


def load_cloud_dataset(root, progress: bool = False) -> dict[str, np.ndarray]:
    """All clouds and ground truth of a cloud dataset, in episode order.

    Returns {points (M, N, 3) float32 hand_base, hinge_angle (M,) rad, tip_gap_m (M,),
    position (M, 3), orientation_xyzw (M, 4), episode (M,) int: rank of the episode's seed}.
    """
    dataset = open_dataset(root)
    if len(dataset) == 0:
        raise ConfigError(f"{root} has no episodes; make one with `hingelab generate clouds --out {root}`")
    parts: dict[str, list] = {k: [] for k in ("points", "hinge_angle", "tip_gap_m", "position",
                                              "orientation_xyzw", "episode")}
    # episode order = seed order (file names sort by time and a random part, not by seed)
    episodes = sorted(dataset.iter_episodes(progress=progress), key=lambda ep: (ep.metadata.get("seed") or 0))
    for k, ep in enumerate(episodes):
        if TOPIC_PRIVILEGED not in ep or "hinge_angle" not in ep[TOPIC_PRIVILEGED]:
            raise ConfigError(f"{ep.path} has no ground-truth opening on /sim/privileged; it is not a cloud "
                              "dataset (make one with `hingelab generate clouds`)")
        priv = ep[TOPIC_PRIVILEGED]
        parts["points"].append(ep.points)
        parts["hinge_angle"].append(priv["hinge_angle"])
        parts["tip_gap_m"].append(np.linalg.norm(priv["tip_a"] - priv["tip_b"], axis=1))
        parts["position"].append(priv["tool_position"])
        parts["orientation_xyzw"].append(priv["tool_orientation"])
        parts["episode"].append(np.full(len(ep.points), k))
    return {key: np.concatenate(value) for key, value in parts.items()}


__all__ = ["CloudDatasetConfig", "SOURCE", "generate_cloud_dataset", "load_cloud_dataset", "nominal_tool_pose",
           "sample_clouds", "write_cloud_episode"]

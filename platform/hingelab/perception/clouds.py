"""Tool point clouds synthesized from the simulator, as the paper makes them.

Each tweezer part (``tool_leg_a``, ``tool_leg_b``) is sampled **once**: trimesh samples
its box geoms' surfaces uniformly (the compiled MuJoCo model's ``geom_size``,
``geom_pos``, ``geom_quat``, so the clouds follow the model), points inside another box
of the same part are dropped (the faces where boxes touch are not surface), and the
result is a bank of points in each part's body frame. A cloud is a random draw from
the bank (without replacement) moved by the parts' simulated poses into ``hand_base``,
then made realistic:

* a pose perturbation (up to 2 cm, 30 degrees; a calibration error, so fixed for an
  episode: ``CloudSynthesizer.new_episode``), applied to the tool pose about its origin;
* per-point Gaussian noise (3 mm);
* random removal of 20% of the points (occlusion); the gap is refilled by repeating
  kept points, as the camera pipeline's fixed-size resampling does, so every cloud
  has exactly ``n_points`` rows (the episode contract: N fixed within an episode).

Frames: the tool frame is ``tool_leg_a``'s (origin on the hinge axis, +x toward the
tips, +z the hinge axis, leg b opens toward +y). Poses are (R (3, 3), t (3,)) mapping
body-frame points into the parent frame: ``p_parent = R @ p_body + t``; metres.
"""

from __future__ import annotations

import functools
import hashlib
from dataclasses import asdict, dataclass

import mujoco
import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from hingelab.errors import AssetError, ConfigError
from hingelab.paths import ASSETS_DIR
from hingelab.perception import generator_draws, pose_kernels
from hingelab.sim import names

TWEEZER_XML = ASSETS_DIR / "tweezer" / "tweezer.xml"
N_POINTS = 256  # points per cloud (the paper's)
BANK_SIZE = 4096  # surface points sampled once per tool (both parts together)
SURFACE_SEED = 0  # the bank is the same on every machine: the canonical cloud depends on it


@dataclass(frozen=True)
class CloudRealism:
    """How far a synthesized cloud departs from the ideal surface sample (paper's values)."""

    noise_std_m: float = 0.003  # per-point Gaussian noise, metres
    removal_fraction: float = 0.2  # fraction of points removed (occlusion)
    max_offset_m: float = 0.02  # per-episode pose perturbation: translation per axis, metres
    max_angle_rad: float = float(np.deg2rad(30.0))  # per-episode perturbation: per Euler angle, rad

    def __post_init__(self):
        if not 0.0 <= self.removal_fraction < 1.0:
            raise ConfigError(f"removal_fraction must be in [0, 1), not {self.removal_fraction}")
        if min(self.noise_std_m, self.max_offset_m, self.max_angle_rad) < 0:
            raise ConfigError(f"cloud realism values must be >= 0: {asdict(self)}")


IDEAL = CloudRealism(0.0, 0.0, 0.0, 0.0)


def pose_matrix(pos: np.ndarray, quat_wxyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), t (3,)) from a MuJoCo position and quaternion (w x y z)."""
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat_wxyz, float))
    return mat.reshape(3, 3), np.asarray(pos, float).copy()


def _box_meshes(model: mujoco.MjModel, body_id: int) -> list[tuple[trimesh.Trimesh, np.ndarray, np.ndarray]]:
    """The body's box geoms as (mesh in body frame, R, centre, half-sizes) tuples."""
    boxes = []
    for g in np.flatnonzero(model.geom_bodyid == body_id):
        if model.geom_type[g] != mujoco.mjtGeom.mjGEOM_BOX:
            raise AssetError(f"tweezer geom {model.geom(g).name!r} is not a box; clouds.py samples boxes only "
                             "(add a sampler for its type)")
        rot, centre = pose_matrix(model.geom_pos[g], model.geom_quat[g])
        transform = np.eye(4)
        transform[:3, :3], transform[:3, 3] = rot, centre
        size = model.geom_size[g].copy()
        boxes.append((trimesh.creation.box(extents=2 * size, transform=transform), rot, centre, size))
    if not boxes:
        raise AssetError(f"body {model.body(body_id).name!r} has no geoms to sample a cloud from")
    return boxes


def _sample_part(model: mujoco.MjModel, body_id: int, count: int, rng: np.random.Generator
                 ) -> tuple[np.ndarray, float]:
    """Uniform surface points of one part (body frame) and the part's outer surface area (m^2).

    Oversamples the concatenated boxes, then drops points lying in another box of the
    part (touching faces are inside the part, not its surface).
    """
    boxes = _box_meshes(model, body_id)
    mesh = trimesh.util.concatenate([b[0] for b in boxes])
    owner = np.repeat(np.arange(len(boxes)), [len(b[0].faces) for b in boxes])
    oversample = 4 * count + 1000
    points, faces = trimesh.sample.sample_surface(mesh, oversample, seed=rng)
    keep = np.ones(len(points), bool)
    for i, (_, rot, centre, size) in enumerate(boxes):
        local = (points - centre) @ rot  # into the box's frame
        inside = np.all(np.abs(local) <= size + 1e-7, axis=1) & (owner[faces] != i)
        keep &= ~inside
    kept = points[keep]
    if len(kept) < count:
        raise AssetError(f"body {model.body(body_id).name!r}: too little outer surface to sample {count} points")
    area = mesh.area * keep.mean()
    return kept[:count], float(area)


class ToolGeometry:
    """The tweezer's sampled surface and its hinge kinematics, from a compiled MuJoCo model.

    Attributes:
        bank_points: (BANK_SIZE, 3) float64, metres, each point in its part's body frame.
        bank_part: (BANK_SIZE,) int8, 0 = leg a, 1 = leg b.
        hinge_range: (low, high) radians, the hinge joint's range.
        geometry_hash: 16 hex digits over the sampled geoms and the hinge: a checkpoint
            trained on another tweezer is refused by comparing it.
    """

    def __init__(self, model: mujoco.MjModel, bank_size: int = BANK_SIZE, seed: int = SURFACE_SEED):
        try:
            self.body_a = model.body(names.TOOL_BODY_A).id
            self.body_b = model.body(names.TOOL_BODY_B).id
            hinge = model.joint(names.TOOL_HINGE).id
        except KeyError as exc:
            raise AssetError(f"the model has no tweezer ({exc}); expected bodies {names.TOOL_BODY_A}, "
                             f"{names.TOOL_BODY_B} and joint {names.TOOL_HINGE}") from exc
        rng = np.random.default_rng(seed)
        counts, parts = [], []
        # first pass for the areas, so the bank is uniform over the whole tool surface
        areas = [_sample_part(model, b, 64, np.random.default_rng(seed))[1] for b in (self.body_a, self.body_b)]
        n_a = int(round(bank_size * areas[0] / sum(areas)))
        for label, (body, n) in enumerate(((self.body_a, n_a), (self.body_b, bank_size - n_a))):
            points, _ = _sample_part(model, body, n, rng)
            parts.append(points)
            counts.append(np.full(n, label, np.int8))
        self.bank_points = np.concatenate(parts)
        self.bank_part = np.concatenate(counts)
        self.part_areas_m2 = tuple(areas)
        # leg b in leg a's frame: body offset, then the hinge rotation about its axis
        self._b_rot, self._b_pos = pose_matrix(model.body_pos[self.body_b], model.body_quat[self.body_b])
        self._axis = model.jnt_axis[hinge].copy()
        self._anchor = model.jnt_pos[hinge].copy()
        self.hinge_range = tuple(float(v) for v in model.jnt_range[hinge])
        tips = [model.site(s).id for s in names.TOOL_TIP_SITES]
        self.tip_a_local = model.site_pos[tips[0]].copy()  # in leg a's frame
        self.tip_b_local = model.site_pos[tips[1]].copy()  # in leg b's frame
        digest = hashlib.sha256()
        for body in (self.body_a, self.body_b):
            for g in np.flatnonzero(model.geom_bodyid == body):
                digest.update(np.round(np.concatenate([model.geom_size[g], model.geom_pos[g],
                                                       model.geom_quat[g]]), 6).tobytes())
        digest.update(np.round(np.concatenate([self._b_pos, self._axis, self._anchor]), 6).tobytes())
        self.geometry_hash = digest.hexdigest()[:16]

    @classmethod
    @functools.cache
    def default(cls) -> "ToolGeometry":
        """The geometry of ``assets/tweezer/tweezer.xml`` (cached: sampled once per process)."""
        if not TWEEZER_XML.exists():
            raise AssetError(f"{TWEEZER_XML} is missing; restore the assets folder")
        return cls(mujoco.MjModel.from_xml_path(str(TWEEZER_XML)))

    # ------------------------------------------------------------------ kinematics
    def leg_b_pose(self, hinge_angle) -> tuple[np.ndarray, np.ndarray]:
        """Leg b's pose in leg a's frame at ``hinge_angle`` (rad; scalar or (B,)): R (..., 3, 3), t (..., 3)."""
        theta = np.asarray(hinge_angle, float)
        hinge_rot = Rotation.from_rotvec(theta[..., None] * self._axis).as_matrix()
        # rotation about the axis through the joint anchor: p -> H (p - a) + a
        rot = self._b_rot @ hinge_rot
        pos = self._b_rot @ self._anchor + self._b_pos - np.einsum("...ij,j->...i", rot, self._anchor)
        return rot, pos

    def tips_in_tool_frame(self, hinge_angle) -> tuple[np.ndarray, np.ndarray]:
        """Tip sites (inner tip faces) of legs a and b in the tool frame, metres: (..., 3) each."""
        rot, pos = self.leg_b_pose(hinge_angle)
        tip_b = np.einsum("...ij,j->...i", rot, self.tip_b_local) + pos
        return np.broadcast_to(self.tip_a_local, tip_b.shape).copy(), tip_b

    def tip_gap_m(self, hinge_angle) -> np.ndarray:
        """Distance between the tip sites, metres, at ``hinge_angle`` (rad)."""
        tip_a, tip_b = self.tips_in_tool_frame(hinge_angle)
        return np.linalg.norm(tip_b - tip_a, axis=-1)

    def surface_in_tool_frame(self, hinge_angle: float, index: np.ndarray | None = None) -> np.ndarray:
        """Bank points (or ``bank_points[index]``) in the tool frame at ``hinge_angle``: (K, 3) float64."""
        index = np.arange(len(self.bank_points)) if index is None else np.asarray(index)
        points, part = self.bank_points[index], self.bank_part[index]
        rot, pos = self.leg_b_pose(hinge_angle)
        out = points.copy()
        out[part == 1] = points[part == 1] @ rot.T + pos
        return out

    def canonical_cloud(self, hinge_angle: float, n_points: int = 1024) -> np.ndarray:
        """A fixed, evenly spread subset of the bank at ``hinge_angle``: (n_points, 3), tool frame.

        Deterministic (the first ``n_points`` of the bank, which is in random order per part,
        taken from both parts by area); registration matches clouds against it.
        """
        index = _even_subset(self.bank_part, n_points)
        return self.surface_in_tool_frame(hinge_angle, index)


def _even_subset(part: np.ndarray, n: int) -> np.ndarray:
    """``n`` bank indices with the parts in the bank's proportions (the bank is shuffled per part)."""
    n_a = int(round(n * (part == 0).mean()))
    return np.concatenate([np.flatnonzero(part == 0)[:n_a], np.flatnonzero(part == 1)[: n - n_a]])


def random_rotations(rng: np.random.Generator, n: int, max_angle_rad: float) -> np.ndarray:
    """(n, 3, 3): Euler angles (xyz) uniform in +-max_angle; uniform over SO(3) if max_angle >= pi."""
    if max_angle_rad >= np.pi:
        return Rotation.random(n, rng=rng).as_matrix()
    angles = rng.uniform(-max_angle_rad, max_angle_rad, (n, 3))
    return Rotation.from_euler("xyz", angles).as_matrix()


class CloudSynthesizer:
    """Clouds of the tweezer from part poses: the sampling and realism of the module docstring.

    Usage, per simulated step (batched: B clouds at a time)::

        synth = CloudSynthesizer(ToolGeometry.default(), CloudRealism(), seed=0)
        synth.new_episode()                  # draws the fixed pose perturbation
        cloud = synth.from_sim(sim.model, sim.data)        # (256, 3) float32, hand_base
        clouds = synth.from_tool_pose(R, t, hinge_angle)   # (B, 256, 3)
    """

    def __init__(self, geometry: ToolGeometry | None = None, realism: CloudRealism = CloudRealism(),
                 seed: int | None = None, n_points: int = N_POINTS):
        if n_points < 16:
            raise ConfigError(f"n_points must be at least 16, not {n_points}")
        self.geometry = geometry or ToolGeometry.default()
        self.realism = realism
        self.n_points = n_points
        self.rng = np.random.default_rng(seed)
        self.perturbation = (np.eye(3), np.zeros(3))  # (R, t) applied to the tool pose
        self._sim_ids: tuple | None = None

    @property
    def n_distinct(self) -> int:
        """How many points of each cloud are distinct: the occlusion removes a share and refills the
        cloud to ``n_points`` with repeats of the kept ones, which ``_sample`` puts last."""
        r = self.realism
        return max(1, self.n_points - int(round(r.removal_fraction * self.n_points)))

    def new_episode(self, seed: int | None = None) -> None:
        """Draw this episode's pose perturbation (and reseed if ``seed`` is given)."""
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        r = self.realism
        rot = random_rotations(self.rng, 1, r.max_angle_rad)[0]
        self.perturbation = (rot, self.rng.uniform(-r.max_offset_m, r.max_offset_m, 3))

    def perturbed_pose(self, rot: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The tool pose the cloud shows: the true pose turned about its origin and shifted."""
        d_rot, d_pos = self.perturbation
        return rot @ d_rot, pos + d_pos

    def from_part_poses(self, rot_a, pos_a, rot_b, pos_b, noise_std_m=None) -> np.ndarray:
        """Clouds from both parts' poses in hand_base: R (B, 3, 3) or (3, 3), t (B, 3) or (3,).

        Returns (B, n_points, 3) or (n_points, 3) float32, metres, hand_base. The
        episode's perturbation moves leg b with leg a (it is an error of the tool pose).
        ``noise_std_m`` (B,): a noise level per cloud instead of the realism's one.
        """
        single = np.ndim(rot_a) == 2
        rot_a, rot_b = (np.ascontiguousarray(np.reshape(x, (-1, 3, 3)), dtype=float) for x in (rot_a, rot_b))
        pos_a, pos_b = (np.ascontiguousarray(np.reshape(x, (-1, 3)), dtype=float) for x in (pos_a, pos_b))
        if not len(rot_a) == len(rot_b) == len(pos_a) == len(pos_b):  # the compiled sampler reads all B of each
            raise ConfigError(f"part poses of different batch sizes: rotations {len(rot_a)} and {len(rot_b)}, "
                              f"positions {len(pos_a)} and {len(pos_b)}")
        clouds = self._sample(rot_a, pos_a, rot_b, pos_b, noise_std_m)
        return clouds[0] if single else clouds

    def from_tool_pose(self, rot, pos, hinge_angle, noise_std_m=None) -> np.ndarray:
        """Clouds from the tool (leg a) pose in hand_base and the hinge angle (rad): see ``from_part_poses``."""
        single = np.ndim(rot) == 2
        rot = np.asarray(rot, float).reshape(-1, 3, 3)
        pos = np.asarray(pos, float).reshape(-1, 3)
        theta = np.broadcast_to(np.asarray(hinge_angle, float).reshape(-1), (len(rot),))
        rel_rot, rel_pos = self.geometry.leg_b_pose(theta)
        rot_b = rot @ rel_rot
        pos_b = np.einsum("bij,bj->bi", rot, rel_pos) + pos
        clouds = self.from_part_poses(rot, pos, rot_b, pos_b, noise_std_m)
        return clouds[0] if single else clouds

    def from_sim(self, model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
        """The cloud of the tweezer as the simulator has it now: (n_points, 3) float32, hand_base."""
        if self._sim_ids is None or self._sim_ids[0] is not model:
            self._sim_ids = (model, model.body(names.HAND_BASE_BODY).id,
                             np.array([model.body(names.TOOL_BODY_A).id, model.body(names.TOOL_BODY_B).id]))
        _, hand, bodies = self._sim_ids
        rot, pos = pose_kernels.hand_frame_poses(data.xmat, data.xpos, hand, bodies)
        return self._sample(rot[:1], pos[:1], rot[1:], pos[1:])[0]

    def _sample(self, rot_a, pos_a, rot_b, pos_b, noise_std_m=None) -> np.ndarray:
        """The draws of the module docstring, then ``pose_kernels.synthesize_clouds`` (placement,
        perturbation, noise and refill in one pass). Each cloud's distinct points are a uniform
        random draw of ``n_distinct`` bank points without replacement, in random order: the same
        distribution as drawing ``n_points`` and removing a random ``removal_fraction`` of them,
        at a fraction of the cost of an argpartition over the whole bank. The batch's
        draws come in a fixed order (points, then noise, then refill), so clouds of one seed
        share their points whatever their noise levels."""
        g, r, n = self.geometry, self.realism, self.n_points
        batch, k = len(rot_a), self.n_distinct
        index = generator_draws.choice(self.rng, len(g.bank_points), k, batch)  # rng.choice's draws, compiled
        std = np.full(batch, r.noise_std_m)  # one level for all, or one per cloud
        noisy = r.noise_std_m > 0
        if noise_std_m is not None:
            std = np.broadcast_to(np.asarray(noise_std_m, float).reshape(-1), (batch,)).copy()
            if std.min() < 0:
                raise ConfigError(f"noise levels must be >= 0, got a minimum of {std.min()}")
            noisy = bool(np.any(std > 0))
        noise = self.rng.standard_normal((batch, k, 3)) if noisy else np.empty((batch, 0, 3))
        refill = generator_draws.integers(self.rng, k, (batch, n - k)) if n > k else np.empty((batch, 0), np.int64)
        d_rot, d_pos = self.perturbation
        return pose_kernels.synthesize_clouds(g.bank_points, g.bank_part, index, refill, noise, std, rot_a, pos_a,
                                              rot_b, pos_b, np.ascontiguousarray(d_rot, dtype=float),
                                              np.ascontiguousarray(d_pos, dtype=float))


__all__ = ["CloudRealism", "CloudSynthesizer", "IDEAL", "N_POINTS", "ToolGeometry", "pose_matrix",
           "random_rotations"]

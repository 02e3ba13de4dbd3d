"""Objects from mesh files: ``mesh:PATH`` (STL, OBJ or PLY, read with trimesh).

The file's vertices are reduced to their convex hull (no convex decomposition: MuJoCo
collides a mesh geom through its convex hull anyway, so a concave mesh grasps like its
hull; the original need not be watertight, only its hull must have volume). The hull is
re-centred on its axis-aligned bounding box's centre (the object body's origin, so
``rest_height`` is half the height, as for the cube) and scaled so its largest extent is
the object's ``size``. The object is placed unrotated: the file's z axis points up and
its y axis is the tweezer tips' closing direction.

A file above ``max_mesh_mb()`` (200 MB unless ``--max-mesh-mb`` raises it) is refused from its
size before it is read. Hulls are cached per (resolved path, modification time, file size), so
an ``ObjectSpec`` keeps only the string and stays frozen and hashable.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from hingelab.bounded_reads import DEFAULT_MAX_MESH_MB, MAX_MESH_MB_ENV, check_file_size, unreadable_reason
from hingelab.errors import ConfigError

MESH_PREFIX = "mesh:"
MESH_SUFFIXES = (".stl", ".obj", ".ply")
FIX = "give an STL, OBJ or PLY file of a solid object (at least 4 non-coplanar vertices)"


def max_mesh_mb() -> float:
    """The largest mesh file read, in MB: ``$HINGELAB_MAX_MESH_MB`` (set by ``--max-mesh-mb``, inherited by
    workers), else ``DEFAULT_MAX_MESH_MB``."""
    text = os.environ.get(MAX_MESH_MB_ENV, "").strip()
    if not text:
        return DEFAULT_MAX_MESH_MB
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value > 0 or value == float("inf"):
        raise ConfigError(f"{MAX_MESH_MB_ENV}={text!r} is not a size in MB; give a positive number, e.g. 500")
    return value


def is_mesh(shape: str) -> bool:
    return isinstance(shape, str) and shape.startswith(MESH_PREFIX)


def mesh_path(shape: str) -> Path:
    """The file of a ``mesh:PATH`` object name (``~`` expanded)."""
    return Path(shape[len(MESH_PREFIX):]).expanduser()


@dataclass(frozen=True)
class UnitHull:
    """A convex hull scaled to largest extent 1, centred on its bounding box's centre."""

    vertices: np.ndarray  # (n, 3)
    edges: np.ndarray  # (m, 2) vertex indices of the hull's edges
    sha256: str  # of the file's bytes

    @property
    def extent(self) -> np.ndarray:
        return self.vertices.max(axis=0) - self.vertices.min(axis=0)

    def width_at(self, z: float) -> float:
        """Extent along y of the hull's slice at height ``z`` above its bottom (unit scale).

        Exact for the hull: the slice of a convex polytope is the convex polygon of the
        points where its edges cross the plane, so the y range over those points is the
        slice's y range.
        """
        v = self.vertices
        zs = v[:, 2] - v[:, 2].min()
        z = float(np.clip(z, 0.0, zs.max()))
        a, b = self.edges[:, 0], self.edges[:, 1]
        za, zb = zs[a], zs[b]
        crossing = (np.minimum(za, zb) <= z) & (np.maximum(za, zb) >= z)
        ys = []
        flat = crossing & np.isclose(za, zb)
        if flat.any():
            ys.append(v[a[flat], 1])
            ys.append(v[b[flat], 1])
        slanted = crossing & ~flat
        if slanted.any():
            t = (z - za[slanted]) / (zb[slanted] - za[slanted])
            ys.append(v[a[slanted], 1] + t * (v[b[slanted], 1] - v[a[slanted], 1]))
        on_plane = np.isclose(zs, z)
        if on_plane.any():
            ys.append(v[on_plane, 1])
        if not ys:
            return 0.0
        y = np.concatenate(ys)
        return float(y.max() - y.min())


def load_unit_hull(shape: str) -> UnitHull:
    """The hull of ``mesh:PATH``'s file (cached), or a one-line ConfigError naming the file."""
    path = mesh_path(shape)
    reason = unreadable_reason(path)
    if reason == "does not exist":
        raise ConfigError(f"mesh file {path} not found; give the path of an existing STL, OBJ or PLY file "
                          f"as --object mesh:PATH")
    if reason is not None:
        raise ConfigError(f"mesh file {path} {reason}; give the path of an STL, OBJ or PLY file as --object mesh:PATH")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ConfigError(f"mesh file {path} has suffix {path.suffix!r}; {FIX}")
    limit_mb = max_mesh_mb()
    check_file_size(path, int(limit_mb * 1e6), "mesh file",
                    f"give a smaller mesh (a convex hull needs few vertices), or raise the limit with "
                    f"--max-mesh-mb (or {MAX_MESH_MB_ENV}=MB)")
    stat = path.stat()
    if stat.st_size == 0:
        raise ConfigError(f"mesh file {path} is empty; {FIX}")
    return _load(str(path.resolve()), stat.st_mtime_ns, stat.st_size)


@lru_cache(maxsize=32)
def _load(path: str, mtime_ns: int, size: int) -> UnitHull:
    import trimesh  # slow to import (over a second) and only mesh: objects need it

    data = Path(path).read_bytes()
    sha = hashlib.sha256(data).hexdigest()
    try:
        mesh = trimesh.load(path, force="mesh")
        vertices = np.asarray(mesh.vertices, dtype=float).reshape(-1, 3)
    except Exception as exc:  # trimesh raises many kinds on malformed files
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise ConfigError(f"mesh file {path} is unreadable ({first}); {FIX}") from None
    vertices = vertices[np.isfinite(vertices).all(axis=1)]
    if len(vertices) < 4:
        raise ConfigError(f"mesh file {path} has {len(vertices)} vertices, no solid; {FIX}")
    scale = float((vertices.max(axis=0) - vertices.min(axis=0)).max())
    centred = vertices - vertices.mean(axis=0)
    singular = np.linalg.svd(centred, compute_uv=False)
    if scale <= 0 or singular[2] <= 1e-6 * singular[0]:
        raise ConfigError(f"mesh file {path} is flat (its vertices are coplanar or collinear), so its hull "
                          f"has no volume; {FIX}")
    try:
        hull = trimesh.convex.convex_hull(vertices / scale)
    except Exception as exc:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise ConfigError(f"mesh file {path} gives no convex hull ({first}); {FIX}") from None
    if len(hull.vertices) < 4 or not hull.volume > 1e-9:
        raise ConfigError(f"mesh file {path} has a hull of zero volume; {FIX}")
    v = np.asarray(hull.vertices, dtype=float)
    low, high = v.min(axis=0), v.max(axis=0)
    v = (v - (low + high) / 2) / float((high - low).max())
    return UnitHull(v, np.asarray(hull.edges_unique, dtype=int), sha)


def mesh_sha256(shape: str) -> str:
    return load_unit_hull(shape).sha256


def object_label(shape: str) -> str:
    """What datasets record as the ``object``: the shape name, or ``mesh:<file name>``."""
    return f"{MESH_PREFIX}{mesh_path(shape).name}" if is_mesh(shape) else shape

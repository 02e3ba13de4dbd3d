"""Procedural object families: ``--object family:NAME[:SEED]`` draws a new object every episode.

An episode's object is a *kind* (one shape) with drawn dimensions, built with trimesh as convex pieces
(one for most kinds; a ring is a union of convex sectors, several geoms in one body, since MuJoCo
collides each mesh through its convex hull):

=============  ====================================================================  ==========
kind           what is drawn                                                         mix
=============  ====================================================================  ==========
ellipsoid      three semi-axes (the shortest one vertical, its stable pose)          train
capsule        radius and length, lying on its side                                  train
rounded_box    three edges and the corner radius, on a face                          train
disc           diameter and thickness (0.25 to 0.7 of it), lying flat                train
coin           diameter, thickness 3 to 4.5 mm and a bevelled rim, lying flat        train
prism3/5/6     a regular 3-, 5- or 6-gon prism's length, standing or lying on a side  holdout
torus          a ring of round section: the tube's radius, lying flat                holdout
washer         a ring of rectangular section: the hole and the thickness, flat      holdout
polytope       the convex hull of 6 to 14 random points, on its stable face          holdout
=============  ====================================================================  ==========

Every kind also draws its largest extent (``size``) uniformly from 8 mm to the size cap and a yaw
about the vertical (uniform over a full turn): "in any orientation" is any heading in a resting pose,
for a tilted capsule or box does not rest; the rest pose is built into the mesh, so the env places it
unrotated. ``NAME`` is a kind, or a group of kinds drawn with equal chances:

* ``prism`` (prism3, prism5, prism6) and ``ring`` (torus, washer);
* ``train``: ellipsoid, capsule, rounded_box, disc, coin: the families to train on;
* ``holdout``: prism3, prism5, prism6, torus, washer, polytope: six shapes in none of ``train``'s
  families and none of the paper's 12 test sets (sphere, cube, cylinder, tetrahedron at 1.5, 2 and
  2.5 cm), never to be trained or tuned on. Each of them is a NAME too, so a held-out evaluation can
  run 30 episodes of each (``--object family:prism5``, ...) or pool them (``family:holdout``).
* ``picksets``: not a drawn mesh but one of the pick table's 12 sets (sphere, cube, cylinder,
  tetrahedron at 1.5, 2 and 2.5 cm, 10 g) per episode, uniformly, as MuJoCo's primitives: training on
  all the sets the pick table measures; ``--size`` does not apply.
* ``train+picksets``: everything there is to train on: per episode the pick sets (as ``picksets``
  draws them) or one of ``train``'s kinds, the six with equal chances (a separate stream of the
  episode's seed chooses, so a kind's draw is the one ``family:train`` would make of it).

Sizes: the largest extent is at most the size cap, ``--size`` (ToolPick-v0's ``size``), which must be
8 to 30 mm (``FAMILY_SIZE_RANGE``; give 0.03 for the whole range: the default 0.02 draws 8 to 20 mm).
Every draw is graspable: at least ``SIZE_LIMITS[0]`` (5 mm) wide along y, the tips' closing direction,
and at least ``MIN_HEIGHT`` (3 mm) tall, so the tips' pads (6 mm below the tip sites, gripping at least
8 mm up) reach it; a draw that is not is drawn again from the same generator. Masses: ``density`` times
the volume (default ``TRAINING_DENSITY``, the paper's training sphere: 10 g at 2 cm diameter, about
2387 kg/m^3), clipped to ``MASS_LIMITS`` (1 g to 200 g); ``--mass`` does not apply.

Draws: episode ``s``'s object comes from ``seeds.object_draw_entropy(s, SEED)``, ``s`` being the seed
the env is reset with (the episode's ``seed`` in its metadata; without one, the seed the env derives);
the family's ``SEED`` picks another set of objects for the same episodes. An object is a pure function
of (kind, parameters): ``build(kind, params)``; the episode records ``record()`` (the parameters as
JSON, the mass and the sha256 of the pieces' vertex and face arrays) and ``rebuild(record)`` builds the
same mesh again, bit for bit on the same numpy, trimesh and qhull.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
import trimesh

from hingelab.errors import ConfigError
from hingelab.seeds import object_draw_entropy
from hingelab.sim.mesh_objects import UnitHull
from hingelab.sim.objects import FAMILY_PREFIX, MASS_LIMITS, MESH_MIN_THICKNESS, PICK_SETS, SIZE_LIMITS, ObjectSpec

FAMILY_SIZE_RANGE = (0.008, 0.030)  # m, the drawn largest extent; the upper end is the size cap's largest value
MIN_HEIGHT = 0.003  # m: lower objects lie under the tips' pads
TRAINING_MASS = 0.010  # kg: the paper's training sphere
TRAINING_DENSITY = TRAINING_MASS / (4.0 / 3.0 * np.pi * 0.01 ** 3)  # kg/m^3: the 10 g sphere of 2 cm diameter
FAMILY_SEED_LIMIT = 2 ** 31  # a family SEED is an integer 0 <= SEED < this
MAX_DRAWS = 100  # attempts at a graspable draw before giving up (none needs more than a few)

TRAIN_KINDS = ("ellipsoid", "capsule", "rounded_box", "disc", "coin")
HOLDOUT_KINDS = ("prism3", "prism5", "prism6", "torus", "washer", "polytope")
KINDS = TRAIN_KINDS + HOLDOUT_KINDS
GROUPS = {"prism": ("prism3", "prism5", "prism6"), "ring": ("torus", "washer"),
          "train": TRAIN_KINDS, "holdout": HOLDOUT_KINDS}
PICK_SETS_NAME = "picksets"  # not drawn meshes: one of the pick table's 12 primitive sets per episode
TRAINING_MIX_NAME = "train+picksets"  # the pick sets (as one entry) or a train kind, the six with equal chances
NAMES = KINDS + tuple(GROUPS) + (PICK_SETS_NAME, TRAINING_MIX_NAME)


def is_family(shape) -> bool:
    return isinstance(shape, str) and shape.startswith(FAMILY_PREFIX)


# ------------------------------------------------------------------ the families' shapes
def _sphere_points(n_lat: int, n_lon: int) -> np.ndarray:
    """Points of a unit sphere on latitude rings, the lowest and highest rings flat polygons (so a
    hull through them rests on a face, not on a pole vertex): (n_lat * n_lon, 3)."""
    lat = -np.pi / 2 + (np.arange(n_lat) + 0.5) * np.pi / n_lat
    lon = 2 * np.pi * np.arange(n_lon) / n_lon
    lat, lon = np.meshgrid(lat, lon, indexing="ij")
    return np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], -1).reshape(-1, 3)


def _polygon(n: int, phase: float = 0.0) -> np.ndarray:
    """A regular n-gon of circumradius 1: (n, 2); ``phase`` rotates it."""
    angle = phase + 2 * np.pi * np.arange(n) / n
    return np.stack([np.cos(angle), np.sin(angle)], -1)


def _extrude(polygon: np.ndarray, half_length: float) -> np.ndarray:
    """A polygon in the xy plane extruded along z to +-half_length: (2n, 3)."""
    n = len(polygon)
    return np.concatenate([np.column_stack([polygon, np.full(n, z)]) for z in (-half_length, half_length)])


def _ellipsoid(p: dict) -> list[np.ndarray]:
    return [_sphere_points(8, 16) * np.asarray(p["semi_axes"], float)]


def _capsule(p: dict) -> list[np.ndarray]:
    ball = _sphere_points(8, 16) * p["radius"]
    return [np.concatenate([ball + [x, 0.0, 0.0] for x in (-p["length"] / 2, p["length"] / 2)])]


def _rounded_box(p: dict) -> list[np.ndarray]:
    half = np.asarray(p["edges"], float) / 2
    radius = p["corner"] * half.min()
    ball = _sphere_points(4, 8) * radius
    corners = [np.array([sx, sy, sz]) * (half - radius) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
    return [np.concatenate([ball + c for c in corners])]


def _disc(p: dict) -> list[np.ndarray]:
    return [_extrude(_polygon(32), p["thickness"] / 2)]


def _coin(p: dict) -> list[np.ndarray]:
    half, bevel = p["thickness"] / 2, p["bevel"]
    rim = _extrude(_polygon(32), half - bevel)
    faces = _extrude(_polygon(32) * (1.0 - bevel), half)
    return [np.concatenate([rim, faces])]


def _prism(p: dict) -> list[np.ndarray]:
    n = p["sides"]
    if p["pose"] == "upright":
        return [_extrude(_polygon(n), p["length"] / 2)]
    section = _polygon(n, -np.pi / 2 + np.pi / n)  # an edge at the bottom: lying on a side face
    points = _extrude(section, p["length"] / 2)  # axis along z ...
    return [points[:, [2, 0, 1]]]  # ... turned to lie along x, the section in the yz plane


def _torus(p: dict) -> list[np.ndarray]:
    """Sectors between consecutive tube sections (each a flat-bottomed polygon): convex pieces."""
    section = _polygon(12, -np.pi / 2 + np.pi / 12) * p["tube"]  # (radial offset, z), radius 1 to the tube's axis
    angles = 2 * np.pi * np.arange(p["segments"] + 1) / p["segments"]
    rings = [np.column_stack([(1.0 + section[:, 0]) * np.cos(a), (1.0 + section[:, 0]) * np.sin(a), section[:, 1]])
             for a in angles]
    return [np.concatenate([rings[i], rings[i + 1]]) for i in range(p["segments"])]


def _washer(p: dict) -> list[np.ndarray]:
    """Annular sectors (inner chord, outer arc through its middle): convex pieces."""
    n, inner, half = p["segments"], p["inner"], p["thickness"] / 2
    pieces = []
    for i in range(n):
        a0, a1 = 2 * np.pi * i / n, 2 * np.pi * (i + 1) / n
        outline = [(inner, a0), (inner, a1), (1.0, a0), (1.0, (a0 + a1) / 2), (1.0, a1)]
        ring = np.array([(r * np.cos(a), r * np.sin(a)) for r, a in outline])
        pieces.append(_extrude(ring, half))
    return pieces


def _polytope(p: dict) -> list[np.ndarray]:
    """The points' hull turned onto its stable face: the face whose plane is nearest the centre of
    mass (the foot of that perpendicular lies inside the face, so it rests there)."""
    points = np.asarray(p["points"], float)
    hull = trimesh.convex.convex_hull(points)
    normals = np.asarray(hull.face_normals)
    distance = np.einsum("ij,ij->i", normals, np.asarray(hull.triangles)[:, 0] - hull.center_mass)
    down = normals[int(np.argmin(distance))]
    return [points @ _rotation_onto(down, np.array([0.0, 0.0, -1.0])).T]


def _rotation_onto(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation matrix turning unit vector ``a`` onto unit vector ``b`` (Rodrigues)."""
    axis, cos = np.cross(a, b), float(np.dot(a, b))
    if np.linalg.norm(axis) < 1e-12:
        return np.eye(3) if cos > 0 else np.diag([1.0, -1.0, -1.0])  # a half turn about x
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + k + k @ k / (1.0 + cos)


BUILDERS = {"ellipsoid": _ellipsoid, "capsule": _capsule, "rounded_box": _rounded_box, "disc": _disc,
            "coin": _coin, "prism3": _prism, "prism5": _prism, "prism6": _prism, "torus": _torus,
            "washer": _washer, "polytope": _polytope}


# ------------------------------------------------------------------ the draws (shape parameters)
def _u(rng: np.random.Generator, low: float, high: float) -> float:
    return float(rng.uniform(low, high))


def _draw_shape(kind: str, rng: np.random.Generator, size: float) -> dict:
    """The kind's parameters beside ``size`` and ``yaw``, in units the build scales away."""
    if kind == "ellipsoid":
        b = _u(rng, 0.55, 1.0)
        return {"semi_axes": [1.0, b, _u(rng, 0.4, b)]}  # the shortest one vertical
    if kind == "capsule":
        return {"radius": 1.0, "length": _u(rng, 0.5, 4.0)}
    if kind == "rounded_box":
        return {"edges": [1.0, _u(rng, 0.5, 1.0), _u(rng, 0.4, 1.0)], "corner": _u(rng, 0.15, 0.8)}
    if kind == "disc":
        return {"thickness": _u(rng, 0.5, 1.4)}  # diameter 2: thickness 0.25 to 0.7 of it
    if kind == "coin":
        thickness = _u(rng, 0.003, 0.0045) / size * 2  # diameter 2, so the size
        return {"thickness": thickness, "bevel": _u(rng, 0.1, 0.3) * thickness}
    if kind.startswith("prism"):
        return {"sides": int(kind[5:]), "length": _u(rng, 0.8, 3.6),
                "pose": "upright" if rng.random() < 0.5 else "lying"}
    if kind == "torus":
        return {"tube": _u(rng, 0.3, 0.75), "segments": 12}
    if kind == "washer":
        return {"inner": _u(rng, 0.35, 0.7), "thickness": _u(rng, 0.3, 0.8), "segments": 12}
    if kind == "polytope":
        n = int(rng.integers(6, 15))
        directions = rng.normal(size=(n, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        stretch = np.array([1.0, _u(rng, 0.6, 1.0), _u(rng, 0.6, 1.0)])
        points = directions * rng.uniform(0.75, 1.0, (n, 1)) * stretch
        return {"points": points.tolist()}
    raise ConfigError(_unknown(kind))


# ------------------------------------------------------------------ building and checking
@dataclass(frozen=True)
class FamilyMesh:
    """A built object: convex pieces in the body frame (metres; origin the bounding box's centre,
    z up, resting on the box's bottom), and the sha256 of their vertex and face arrays."""

    kind: str
    params: dict
    pieces: tuple  # of trimesh.Trimesh, each convex and watertight
    sha256: str

    @property
    def mesh(self) -> trimesh.Trimesh:
        """The pieces as one mesh (a ring's pieces touch: a union, not one watertight solid)."""
        return trimesh.util.concatenate(list(self.pieces))

    @property
    def extent(self) -> np.ndarray:
        v = np.concatenate([np.asarray(p.vertices) for p in self.pieces])
        return v.max(axis=0) - v.min(axis=0)

    @property
    def volume(self) -> float:
        return float(sum(p.volume for p in self.pieces))


def mesh_sha256(pieces) -> str:
    """sha256 over each piece's vertices (float64) and faces (int64), shapes included, in order."""
    digest = hashlib.sha256()
    for piece in pieces:
        for array in (np.ascontiguousarray(piece.vertices, "<f8"), np.ascontiguousarray(piece.faces, "<i8")):
            digest.update(np.asarray(array.shape, "<i8").tobytes())
            digest.update(array.tobytes())
    return digest.hexdigest()


def _canonical(params: dict) -> str:
    return json.dumps(params, sort_keys=True, separators=(",", ":"))


def build(kind: str, params: dict) -> FamilyMesh:
    """The object of ``kind`` with ``params`` (``size`` and ``yaw`` among them): a pure function."""
    if kind not in BUILDERS:
        raise ConfigError(_unknown(kind))
    return _build(kind, _canonical(params))


@lru_cache(maxsize=256)
def _build(kind: str, params_json: str) -> FamilyMesh:
    params = json.loads(params_json)
    try:
        raw = BUILDERS[kind](params)
        size, yaw = float(params["size"]), float(params["yaw"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"object parameters {params_json} do not describe a {kind} ({exc!r})") from None
    c, s = np.cos(yaw), np.sin(yaw)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    points = [np.asarray(p, float) @ turn.T for p in raw]
    every = np.concatenate(points)
    low, high = every.min(axis=0), every.max(axis=0)
    scale = size / float((high - low).max())
    # hull vertices are a subset of the points, so the pieces' bounding box is the points'
    pieces = tuple(trimesh.convex.convex_hull((p - (low + high) / 2) * scale) for p in points)
    return FamilyMesh(kind, params, pieces, mesh_sha256(pieces))


def graspable_problem(mesh: FamilyMesh) -> str | None:
    """Why the tweezer could not pick ``mesh`` (None: it can): too narrow along y, too low, a sheet, or a
    piece without volume (each piece is a convex hull, so convex and watertight by construction)."""
    x, y, z = mesh.extent
    if y < SIZE_LIMITS[0]:
        return f"{1000 * y:.1f} mm wide along y (at least {1000 * SIZE_LIMITS[0]:g})"
    if z < MIN_HEIGHT:
        return f"{1000 * z:.1f} mm tall (at least {1000 * MIN_HEIGHT:g})"
    if x < MESH_MIN_THICKNESS:
        return f"{1000 * x:.2f} mm thick along x (at least {1000 * MESH_MIN_THICKNESS:g})"
    if min(piece.volume for piece in mesh.pieces) <= 1e-12:
        return "a piece has no volume"
    return None


# ------------------------------------------------------------------ a family, its draws, the drawn object
@dataclass(frozen=True)
class DrawnObject(ObjectSpec):
    """An object drawn from a family: an ``ObjectSpec`` whose collision geometry is ``pieces`` (vertices
    in the body frame, metres) and whose shape is ``family:KIND``. ``record`` says how to build it again."""

    record_json: str = ""
    pieces: tuple = field(default=(), compare=False, repr=False)  # of (vertices (n, 3) m, mass kg)
    hull: UnitHull | None = field(default=None, compare=False, repr=False)  # of all pieces, unit scale

    def __post_init__(self):  # the family's build has checked the geometry; the scene's limits still hold
        if not (SIZE_LIMITS[0] <= self.size <= SIZE_LIMITS[1] and MASS_LIMITS[0] <= self.mass <= MASS_LIMITS[1]):
            raise ConfigError(f"drawn object {self.shape} of {self.size!r} m, {self.mass!r} kg is outside the "
                              f"scene's limits")

    @property
    def is_mesh(self) -> bool:
        return True

    @property
    def record(self) -> dict:
        return json.loads(self.record_json)

    def _unit_hull(self) -> UnitHull:
        return self.hull

    def mesh_pieces(self) -> list[tuple[np.ndarray, float]]:
        return list(self.pieces)


@dataclass(frozen=True)
class ChosenObject(ObjectSpec):
    """A fixed shape drawn by a family (``family:picksets``): an ``ObjectSpec`` with the draw's ``record``."""

    record_json: str = ""

    @property
    def record(self) -> dict:
        return json.loads(self.record_json)


@dataclass(frozen=True)
class ObjectFamily:
    """``family:NAME[:SEED]`` with its size cap (m) and density (kg/m^3): ``draw(episode_seed)``."""

    name: str
    seed: int | None = None
    size_cap: float = FAMILY_SIZE_RANGE[1]
    density: float = TRAINING_DENSITY
    # the pick sets' chances (PICK_SETS order, summing to 1); None: uniform, the draws of every earlier run
    set_weights: tuple[float, ...] | None = None

    @classmethod
    def parse(cls, text: str, size_cap: float, density: float = TRAINING_DENSITY) -> ObjectFamily:
        """``family:NAME[:SEED]`` -> an ObjectFamily, or a one-line ConfigError naming the choices."""
        parts = text[len(FAMILY_PREFIX):].split(":") if is_family(text) else []
        if not 1 <= len(parts) <= 2 or parts[0] not in NAMES:
            raise ConfigError(_unknown(parts[0] if len(parts) == 1 else text))
        seed = None
        if len(parts) == 2:
            if not parts[1].isdigit() or int(parts[1]) >= FAMILY_SEED_LIMIT:
                raise ConfigError(f"object family seed {parts[1]!r} in {text!r} is not an integer from 0 to "
                                  f"{FAMILY_SEED_LIMIT - 1}; give family:NAME or family:NAME:SEED")
            seed = int(parts[1])
        low, high = FAMILY_SIZE_RANGE
        if not (np.isfinite(size_cap) and low <= size_cap <= high + 1e-12):
            raise ConfigError(f"{text}: --size {size_cap!r} m is out of range: a family's objects are "
                              f"{1000 * low:g} to {1000 * high:g} mm and --size caps their largest extent "
                              f"(give {low} to {high}, e.g. 0.03 for all of them)")
        if not (np.isfinite(density) and density > 0):
            raise ConfigError(f"{text}: density {density!r} kg/m^3 must be positive")
        return cls(parts[0], seed, float(min(size_cap, high)), float(density))

    @property
    def kinds(self) -> tuple[str, ...]:
        if self.name == TRAINING_MIX_NAME:
            return TRAIN_KINDS
        return GROUPS.get(self.name, (self.name,))

    @property
    def label(self) -> str:
        return FAMILY_PREFIX + self.name + ("" if self.seed is None else f":{self.seed}")

    def draw_mesh(self, episode_seed: int) -> FamilyMesh:
        """Episode ``episode_seed``'s object: a kind of the family, then its size, shape and yaw, drawn
        again until graspable."""
        rng = np.random.default_rng(object_draw_entropy(episode_seed, self.seed))
        kind = self.kinds[int(rng.integers(len(self.kinds)))]
        problem = None
        for _ in range(MAX_DRAWS):
            size = _u(rng, FAMILY_SIZE_RANGE[0], self.size_cap)
            params = {"size": size, **_draw_shape(kind, rng, size), "yaw": _u(rng, 0.0, 2 * np.pi)}
            mesh = build(kind, params)
            problem = graspable_problem(mesh)
            if problem is None:
                return mesh
        raise ConfigError(f"{self.label}: no graspable {kind} in {MAX_DRAWS} draws up to {self.size_cap:g} m "
                          f"(the last: {problem}); give a larger --size")

    def draw(self, episode_seed: int) -> ObjectSpec:
        if self.name == PICK_SETS_NAME:
            return self.draw_pick_set(episode_seed)
        if self.name == TRAINING_MIX_NAME:
            choice = np.random.default_rng([*object_draw_entropy(episode_seed, self.seed), 1])
            if int(choice.integers(len(TRAIN_KINDS) + 1)) == 0:
                return self.draw_pick_set(episode_seed)
        return drawn_object(self.draw_mesh(episode_seed), self.density, self.label)

    def draw_pick_set(self, episode_seed: int) -> ChosenObject:
        """``family:picksets``: one of the pick table's 12 shape-size sets, uniformly, at the training object's
        mass (what ``eval high --object SHAPE --size SIZE`` picks), as MuJoCo's own primitives."""
        rng = np.random.default_rng(object_draw_entropy(episode_seed, self.seed))
        if self.set_weights is None:
            shape, size = PICK_SETS[int(rng.integers(len(PICK_SETS)))]
        else:
            shape, size = PICK_SETS[int(rng.choice(len(PICK_SETS), p=self.set_weights))]
        record = {"family": self.label, "kind": shape, "params": {"size": size}, "size_m": size,
                  "mass_kg": TRAINING_MASS, "mesh_sha256": None}
        return ChosenObject(shape, size, TRAINING_MASS, record_json=_canonical(record))


def pick_set_weights(weights: dict, family: ObjectFamily | None, where: str = "pick_set_weights") -> tuple[float, ...]:
    """``{"SHAPE:SIZE": weight}`` (sizes in m as the pick table names them, e.g. ``"tetrahedron:0.015"``; a set
    not named weighs 1) -> the chances of the 12 pick sets, in ``PICK_SETS`` order; a one-line ConfigError for
    a family that draws no pick sets, an unknown set or a weight that is not a positive finite number."""
    if family is None or family.name not in (PICK_SETS_NAME, TRAINING_MIX_NAME):
        raise ConfigError(f"{where} weighs the pick sets of family:{PICK_SETS_NAME} or family:{TRAINING_MIX_NAME}; "
                          f"the object is {family.label if family else 'not a family'}")
    names = {f"{shape}:{size:g}": i for i, (shape, size) in enumerate(PICK_SETS)}
    chances = np.ones(len(PICK_SETS))
    for key, weight in dict(weights).items():
        if key not in names:
            raise ConfigError(f"{where}: {key!r} is not a pick set; give SHAPE:SIZE, one of {', '.join(names)}")
        if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not (np.isfinite(weight) and weight > 0):
            raise ConfigError(f"{where}: the weight of {key} must be a positive number, not {weight!r}")
        chances[names[key]] = float(weight)
    return tuple(float(c) for c in chances / chances.sum())


def drawn_object(mesh: FamilyMesh, density: float = TRAINING_DENSITY, label: str = "") -> DrawnObject:
    """The ``ObjectSpec`` of a built mesh: mass from ``density`` (clipped to the scene's limits), split
    over the pieces by volume."""
    volumes = np.array([p.volume for p in mesh.pieces])
    mass = float(np.clip(density * volumes.sum(), *MASS_LIMITS))
    size = float(mesh.params["size"])
    record = {"family": label, "kind": mesh.kind, "params": mesh.params, "size_m": size,
              "density_kg_m3": float(density), "mass_kg": mass, "mesh_sha256": mesh.sha256}
    pieces = tuple((np.array(p.vertices, float), float(mass * v / volumes.sum()))  # a copy: the build is cached
                   for p, v in zip(mesh.pieces, volumes))
    every = np.concatenate([v for v, _ in pieces])
    outline = trimesh.convex.convex_hull(every)
    hull = UnitHull(np.asarray(outline.vertices, float) / size, np.asarray(outline.edges_unique, int), mesh.sha256)
    return DrawnObject(f"{FAMILY_PREFIX}{mesh.kind}", size, mass, record_json=_canonical(record), pieces=pieces,
                       hull=hull)


def check_object(object: str, size: float, mass: float) -> None:
    """The one-line ConfigError ToolPick-v0 gives for ``object``, ``size`` and ``mass`` (nothing built: a
    family's name, SEED and size cap, or the ObjectSpec's checks)."""
    if is_family(object):
        ObjectFamily.parse(object, size)
    else:
        ObjectSpec(object, size, mass)


def episode_record(object: str, size_cap: float, episode_seed: int) -> dict | None:
    """What an episode reset with ``episode_seed`` records of its object: the draw's ``record`` for
    ``family:...``, None for a fixed object."""
    if not is_family(object):
        return None
    return ObjectFamily.parse(object, size_cap).draw(episode_seed).record


def rebuild(record: dict, check: bool = True) -> FamilyMesh:
    """The mesh an episode recorded (its ``record``): built again from kind and parameters; ``check``:
    a ConfigError unless its sha256 is the recorded one."""
    if record.get("mesh_sha256") is None:
        raise ConfigError(f"{record.get('family')}'s {record['kind']} is a MuJoCo primitive, not a drawn mesh: "
                          f"build it as ObjectSpec({record['kind']!r}, {record['size_m']})")
    mesh = build(record["kind"], record["params"])
    if check and mesh.sha256 != record.get("mesh_sha256"):
        raise ConfigError(f"the {record['kind']} rebuilt from its parameters has sha256 {mesh.sha256[:12]}..., "
                          f"not the recorded {str(record.get('mesh_sha256'))[:12]}... (another numpy, trimesh or "
                          "qhull?)")
    return mesh


def _unknown(name: str) -> str:
    return (f"unknown object family {name!r}; choose family:NAME[:SEED] with NAME one of: {', '.join(NAMES)} "
            f"(train: {', '.join(TRAIN_KINDS)}; holdout: {', '.join(HOLDOUT_KINDS)}; {PICK_SETS_NAME}: the pick "
            f"table's 12 shape-size sets; {TRAINING_MIX_NAME}: either)")


__all__ = ["FAMILY_SIZE_RANGE", "GROUPS", "PICK_SETS_NAME", "TRAINING_MIX_NAME", "ChosenObject",
           "HOLDOUT_KINDS", "KINDS", "MIN_HEIGHT", "NAMES", "TRAINING_DENSITY",
           "TRAIN_KINDS", "DrawnObject", "FamilyMesh", "ObjectFamily", "build", "check_object", "drawn_object",
           "episode_record", "graspable_problem", "is_family", "mesh_sha256", "rebuild"]

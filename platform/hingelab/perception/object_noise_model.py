"""A statistical model of the depth camera's object estimate, so that training sees its errors without rendering.

``hingelab diagnose object-estimate`` measures each estimator of ``hingelab.perception.object_estimate`` on
rendered frames (its ``frames.csv``: one row per frame and estimator). ``fit`` turns those rows into a small
model; ``FittedObjectEstimate`` draws from it in ToolPick-v0 (``object_noise="fitted:ESTIMATOR"``) where the
camera path (``object_perception``) would render and estimate.

The centre's error is modelled in the **ray frame** (``ray_frame``): the axis toward the camera along the ray
from the rig camera's optical centre to the object's true centre, and two axes across it (``right``: level;
``up``: perpendicular to both). Per (estimator, shape, size), from the frames that gave an estimate, in mm:

* ``bias`` (3,): the median error per axis;
* ``scale`` (3,): the core's spread per axis, 1.4826 x the median absolute deviation (a Gaussian's std);
* ``outlier``: the frames more than ``OUTLIER_SIGMAS`` core scales from the bias on some axis (a wrongly
  segmented blob, a frame of few points), their share ``p`` and their mean ``shift`` (3,) and ``scale`` (3,)
  about the bias; too few of them (under ``MIN_OUTLIERS``) and the shift and scale are the estimator's pooled
  outliers';
* ``dropout``: the share of frames that gave no estimate (flagged);
* ``extent_bias`` and ``extent_scale`` (3,): the visible extent's error against the true bounding box, per
  world axis (x, y, z), median and 1.4826 x MAD, when the rows record it (else None: the env keeps its
  Gaussian for the extent).

A draw: with probability ``dropout`` no estimate; else bias + N(0, scale), or with probability ``p``
bias + shift + N(0, outlier scale). Sizes between the fitted ones interpolate the parameters linearly, sizes
outside take the nearest; a shape the model does not know (a mesh, a family's kind) takes the estimator's pooled
entry (shape and size ``"all"``). A temporal filter (``temporal_NAME``, the median of the last ``window`` estimates
of ``NAME``) is not fitted as independent draws, its errors being correlated from step to step: its entry is
``filters[temporal_NAME] = {"of": NAME, "window": W}`` and ``FittedObjectEstimate`` runs the filter
(``object_estimate.TemporalFilter``) over draws of ``NAME``.

The model's JSON: ``format``, ``version`` (``MODEL_VERSION``), ``code_version``, ``seed`` (of the residuals'
sampling), ``source`` (the rows' file, its sha256 and row count), ``camera_position_m``, ``axes``, ``entries``
(one per estimator, shape and size, and pooled) and ``filters``. ``load`` refuses a missing, corrupt or
other-version file with one line.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from hingelab.errors import ConfigError
from hingelab.json_text import strict_dumps
from hingelab.paths import ANALYSIS_DIR
from hingelab.perception.object_estimate import ESTIMATORS, TemporalFilter
from hingelab.sim.rig_camera import RIG_VIEW, camera_world_position

GAUSSIAN = "gaussian"  # ToolPick-v0's default: the truth with its 2 mm Gaussian noise
FITTED_PREFIX = "fitted:"
DEFAULT_MODEL = ANALYSIS_DIR / "objects" / "noise-model" / "object_noise_model.json"
MODEL_FORMAT = "hingelab.object_noise_model"
MODEL_VERSION = 1
AXES = ("toward_camera", "right", "up")
EXTENT_AXES = ("x", "y", "z")
ERROR_COLUMNS = ("ray_bias_mm", "across_right_mm", "across_up_mm")  # frames.csv's columns of AXES
EXTENT_COLUMNS = ("extent_error_x_mm", "extent_error_y_mm", "extent_error_z_mm")
MAD_TO_STD = 1.4826
OUTLIER_SIGMAS = 3.0
MIN_OUTLIERS = 3
MIN_SCALE_MM = 0.05  # a floor, so a key of identical frames still draws
POOLED = "all"
TEMPORAL_PREFIX = "temporal_"
# the rig camera's optical centre in ToolPick-v0's world (fixed in the world: hingelab.sim.rig_camera)
RIG_CAMERA_POSITION = camera_world_position(RIG_VIEW, "tool_pick")


def ray_frame(camera_position: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(3, 3) the ray frame's axes as columns, world: toward the camera along the ray camera -> ``truth``; right
    (level, right of the ray seen from the camera); up (perpendicular to both, upward). ``R @ e_ray`` is a
    world vector, ``R.T @ e_world`` its components."""
    ray = np.asarray(truth, float) - np.asarray(camera_position, float)
    ray /= np.linalg.norm(ray)
    right = np.cross(ray, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    return np.stack([-ray, right, np.cross(right, ray)], axis=1)


# ---------------------------------------------------------------------- fitting
def _spread(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(median, 1.4826 MAD) per column of ``values`` (N, 3), floored at ``MIN_SCALE_MM``."""
    centre = np.median(values, axis=0)
    scale = MAD_TO_STD * np.median(np.abs(values - centre), axis=0)
    return centre, np.maximum(scale, MIN_SCALE_MM)


def _fit_errors(errors: np.ndarray) -> dict:
    """Bias, core scale and the outliers of (N, 3) errors, mm."""
    bias, scale = _spread(errors)
    deviation = errors - bias
    outliers = np.any(np.abs(deviation) > OUTLIER_SIGMAS * scale, axis=1)
    # the outliers' own shift and scale; placeholders until the pooled ones replace too few
    far = deviation[outliers]
    shift = far.mean(axis=0) if len(far) else np.zeros(3)
    spread = far.std(axis=0) if len(far) > 1 else np.zeros(3)
    return {"bias": bias, "scale": scale, "outlier_p": float(outliers.mean()), "outlier_shift": shift,
            "outlier_scale": np.maximum(spread, scale), "outliers": int(outliers.sum())}


def _entry(estimator: str, shape: str, size, rows: list[dict]) -> dict:
    good = [r for r in rows if not r["flag"]]
    entry = {"estimator": estimator, "shape": shape, "size_m": size, "frames": len(rows), "estimates": len(good),
             "dropout": round(1 - len(good) / len(rows), 4) if rows else 0.0}
    if not good:  # every frame flagged: the pooled entry's error, this key's dropout
        return {**entry, "fit": None}
    fit = _fit_errors(np.array([[float(r[c]) for c in ERROR_COLUMNS] for r in good]))
    extent = np.array([[float(r.get(c, np.nan)) for c in EXTENT_COLUMNS] for r in good])
    extent = extent[np.isfinite(extent).all(axis=1)]
    extent_fit = _spread(extent) if len(extent) else (None, None)
    return {**entry, "fit": fit, "extent": extent_fit}


def _rounded(v) -> list[float] | None:
    return None if v is None else [round(float(x), 3) for x in v]


def _serialize(entry: dict, pooled_outliers: dict) -> dict:
    fit = entry.pop("fit")
    extent_bias, extent_scale = entry.pop("extent", (None, None))
    if fit is None:
        return {**entry, "bias_mm": None}
    shift, spread = fit["outlier_shift"], fit["outlier_scale"]
    if fit["outliers"] < MIN_OUTLIERS and pooled_outliers:
        shift, spread = pooled_outliers["shift"], np.maximum(pooled_outliers["scale"], fit["scale"])
    return {**entry, "bias_mm": _rounded(fit["bias"]), "scale_mm": _rounded(fit["scale"]),
            "outlier_p": round(fit["outlier_p"], 4), "outlier_shift_mm": _rounded(shift),
            "outlier_scale_mm": _rounded(spread), "extent_bias_mm": _rounded(extent_bias),
            "extent_scale_mm": _rounded(extent_scale)}


def fit(rows: list[dict], source: dict | None = None, seed: int = 0, code_version: dict | None = None) -> dict:
    """The model (a JSON-ready dict) of ``rows`` (``frames.csv``'s: ``estimator``, ``shape``, ``size_m``, ``flag``
    and the ``ERROR_COLUMNS``, optionally the ``EXTENT_COLUMNS``), for every per-frame estimator in them; the
    ``temporal_*`` rows name the filters. ``source``: where the rows came from; ``seed``: the residuals'."""
    missing = [c for c in ("estimator", "shape", "size_m", "flag", *ERROR_COLUMNS) if rows and c not in rows[0]]
    if not rows or missing:
        raise ConfigError("the frames table has no rows" if not rows else
                          f"the frames table lacks the columns {', '.join(missing)}: remake it with `hingelab "
                          "diagnose object-estimate` (the across-ray columns came in with the noise model)")
    entries = []
    for estimator in dict.fromkeys(r["estimator"] for r in rows if not r["estimator"].startswith(TEMPORAL_PREFIX)):
        mine = [r for r in rows if r["estimator"] == estimator]
        keys = dict.fromkeys((r["shape"], float(r["size_m"])) for r in mine)
        raw = [_entry(estimator, shape, size, [r for r in mine if (r["shape"], float(r["size_m"])) == (shape, size)])
               for shape, size in keys]
        pooled = _entry(estimator, POOLED, POOLED, mine)
        pooled_outliers = {}
        if pooled["fit"] is not None:
            pooled_outliers = {"shift": pooled["fit"]["outlier_shift"], "scale": pooled["fit"]["outlier_scale"]}
        entries += [_serialize(e, pooled_outliers) for e in [*raw, pooled]]
    filters = {}
    for name in dict.fromkeys(r["estimator"] for r in rows if r["estimator"].startswith(TEMPORAL_PREFIX)):
        base = name[len(TEMPORAL_PREFIX):]
        spots = {}
        for r in rows:
            if r["estimator"] == base:
                key = (r["shape"], r["size_m"], r.get("spot"))
                spots[key] = spots.get(key, 0) + 1
        window = max(spots.values()) if spots else 5
        filters[name] = {"of": base, "window": int(window)}
    return {"format": MODEL_FORMAT, "version": MODEL_VERSION, "code_version": code_version or {}, "seed": seed,
            "source": source or {}, "camera_position_m": [round(float(v), 4) for v in RIG_CAMERA_POSITION],
            "axes": list(AXES), "extent_axes": list(EXTENT_AXES), "units": "mm", "entries": entries,
            "filters": filters}


def save(model: dict, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(strict_dumps(model, path, indent=1) + "\n")
    return path


# ---------------------------------------------------------------------- using it
class ObjectNoiseModel:
    """A loaded model: ``params(estimator, shape, size)`` -> the drawing parameters (interpolated in size)."""

    def __init__(self, data: dict, path: str = "<memory>"):
        self.data, self.path = data, str(path)
        self.sha256 = hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()
        self._entries: dict[str, dict] = {}
        for entry in data["entries"]:
            by_shape = self._entries.setdefault(entry["estimator"], {})
            by_shape.setdefault(entry["shape"], []).append(entry)
        for by_shape in self._entries.values():
            for shape in by_shape:
                by_shape[shape].sort(key=lambda e: -1.0 if e["size_m"] == POOLED else float(e["size_m"]))
        self.filters: dict = data.get("filters", {})

    @property
    def estimators(self) -> list[str]:
        return [*self._entries, *(f for f in self.filters if self.filters[f]["of"] in self._entries)]

    def check_estimator(self, estimator: str) -> str:
        if estimator not in self.estimators:
            raise ConfigError(f"the object noise model {self.path} has no estimator {estimator!r}; it has "
                              f"{', '.join(self.estimators)}")
        return estimator

    def base(self, estimator: str) -> tuple[str, int | None]:
        """(the per-frame estimator drawn, the temporal filter's window or None)."""
        self.check_estimator(estimator)
        if estimator in self.filters:
            return self.filters[estimator]["of"], int(self.filters[estimator]["window"])
        return estimator, None

    def params(self, estimator: str, shape: str, size: float) -> dict:
        """The entry (``bias_mm`` ... ``extent_scale_mm`` as arrays, ``dropout``, ``outlier_p``) of a per-frame
        ``estimator`` for ``shape`` and ``size`` (m): interpolated between fitted sizes, the nearest outside them,
        the pooled entry for an unknown shape; a key whose frames were all flagged keeps its dropout and takes
        the pooled error."""
        by_shape = self._entries[self.check_estimator(estimator)]
        pooled = by_shape[POOLED][0]
        entries = [e for e in by_shape.get(shape, []) if e["size_m"] != POOLED]
        if not entries:
            return _arrays(pooled, pooled)
        sizes = np.array([float(e["size_m"]) for e in entries])
        if size <= sizes[0] or size >= sizes[-1] or len(entries) == 1:
            return _arrays(entries[int(np.argmin(np.abs(sizes - size)))], pooled)
        hi = int(np.searchsorted(sizes, size))
        w = (size - sizes[hi - 1]) / (sizes[hi] - sizes[hi - 1])
        low, high = _arrays(entries[hi - 1], pooled), _arrays(entries[hi], pooled)
        return {k: (None if low[k] is None or high[k] is None else (1 - w) * low[k] + w * high[k])
                if k not in ("estimator", "shape") else low[k] for k in low}


_NUMERIC = ("dropout", "outlier_p")
_VECTORS = ("bias_mm", "scale_mm", "outlier_shift_mm", "outlier_scale_mm", "extent_bias_mm", "extent_scale_mm")


def _arrays(entry: dict, pooled: dict) -> dict:
    error = entry if entry.get("bias_mm") is not None else pooled
    out = {"estimator": entry["estimator"], "shape": entry["shape"], "dropout": float(entry["dropout"]),
           "outlier_p": float(error["outlier_p"])}
    for k in _VECTORS:
        value = error.get(k)
        out[k] = None if value is None else np.asarray(value, float)
    return out


def load(path) -> ObjectNoiseModel:
    """The model at ``path``; one clear line if it is missing, not JSON, not a model or another version."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"no object noise model at {path}: fit one with `hingelab diagnose object-noise-fit`")
    try:
        text = path.read_bytes()
        data = json.loads(text)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"the object noise model {path} is not readable JSON ({exc.__class__.__name__}): refit it "
                          "with `hingelab diagnose object-noise-fit`") from None
    if not isinstance(data, dict) or data.get("format") != MODEL_FORMAT:
        raise ConfigError(f"{path} is not an object noise model (format {MODEL_FORMAT!r})")
    if data.get("version") != MODEL_VERSION:
        raise ConfigError(f"the object noise model {path} is version {data.get('version')!r}; this code reads "
                          f"version {MODEL_VERSION}: refit it with `hingelab diagnose object-noise-fit`")
    try:
        model = ObjectNoiseModel(data, path)
        model.sha256 = hashlib.sha256(text).hexdigest()  # the file's, as a dataset records it
        for estimator in model.estimators:
            model.params(model.base(estimator)[0], POOLED, 0.0)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise ConfigError(f"the object noise model {path} is corrupt ({exc.__class__.__name__}: {exc}): refit it "
                          "with `hingelab diagnose object-noise-fit`") from None
    return model


def draw_error(params: dict, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """Errors in the ray frame (``AXES``), m: (3,) or (n, 3); dropouts are not drawn here."""
    shape = (3,) if n is None else (n, 3)
    core = params["bias_mm"] + params["scale_mm"] * rng.standard_normal(shape)
    far = params["bias_mm"] + params["outlier_shift_mm"] + params["outlier_scale_mm"] * rng.standard_normal(shape)
    pick = rng.random(() if n is None else (n, 1)) < params["outlier_p"]
    return np.where(pick, far, core) / 1000.0


class FittedObjectEstimate:
    """The camera's object estimate drawn from a fitted model, with ``CameraObjectEstimate``'s interface.

    ``new_episode(seed, shape, size)``, then ``observe(truth, true_extent)`` once per step (``truth``: the object's
    centre, world, m; ``true_extent`` (3,) m). A dropout (a frame without an estimate, flag ``"dropout"``) keeps the
    last estimate, as the camera path does; the episode's first frame always gives one (a rig waits for its first
    estimate before it starts). ``estimate``, ``extent`` (None when the model has no extent fit: the env then keeps
    its Gaussian), ``fresh``, ``flag``. Draws come from the episode's own stream (the env's others do not shift)."""

    points = None  # no visible points: nothing rendered
    n_points = 0

    def __init__(self, model: ObjectNoiseModel, estimator: str, camera_position: np.ndarray = RIG_CAMERA_POSITION):
        self.model, self.estimator = model, estimator
        self.base, self.window = model.base(estimator)
        self.camera_position = np.asarray(camera_position, float)
        self.rng = np.random.default_rng()
        self.params = model.params(self.base, POOLED, 0.0)
        self.filter = TemporalFilter(self.window) if self.window else None
        self._clear()

    def _clear(self) -> None:
        self.estimate: np.ndarray | None = None
        self.extent: np.ndarray | None = None
        self.fresh, self.flag = False, None
        if self.filter is not None:
            self.filter.reset()

    def new_episode(self, seed: int | None, shape: str, size: float) -> None:
        self.rng = np.random.default_rng(None if seed is None else [seed, 45])
        self.params = self.model.params(self.base, shape, size)
        self._clear()

    def observe(self, truth: np.ndarray, true_extent: np.ndarray) -> None:
        truth = np.asarray(truth, float)
        p = self.params
        # the draws in a fixed order whatever happens, so a dropout does not shift the stream
        dropped = self.rng.random() < p["dropout"]
        error = ray_frame(self.camera_position, truth) @ draw_error(p, self.rng)
        extent_noise = self.rng.standard_normal(3)
        if dropped and self.estimate is not None:
            self.fresh, self.flag = False, "dropout"
            return
        estimate = truth + error
        self.estimate = self.filter.update(estimate) if self.filter is not None else estimate
        if p["extent_bias_mm"] is not None:
            self.extent = np.maximum(np.asarray(true_extent, float) +
                                     (p["extent_bias_mm"] + p["extent_scale_mm"] * extent_noise) / 1000.0, 0.0)
        self.fresh, self.flag = True, None

    @property
    def centre(self) -> np.ndarray:
        return self.estimate

    @property
    def box(self) -> np.ndarray | None:
        return self.extent


def fitted_estimator(object_noise: str) -> str | None:
    """The estimator of an ``object_noise`` setting: None for ``"gaussian"``, NAME for ``"fitted:NAME"`` (a
    per-frame estimator or ``temporal_NAME``); one line for anything else."""
    names = [*ESTIMATORS, *(f"{TEMPORAL_PREFIX}{n}" for n in ESTIMATORS)]
    if object_noise == GAUSSIAN:
        return None
    estimator = object_noise[len(FITTED_PREFIX):] if str(object_noise).startswith(FITTED_PREFIX) else None
    if estimator not in names:
        raise ConfigError(f"object noise {object_noise!r} is unknown; choose {GAUSSIAN} or {FITTED_PREFIX}NAME with "
                          f"NAME one of {', '.join(names)} (e.g. {FITTED_PREFIX}ray_corrected)")
    return estimator


def make_fitted(object_noise: str, model_path=None) -> FittedObjectEstimate | None:
    """The drawer of an ``object_noise`` setting from the model at ``model_path`` (default ``DEFAULT_MODEL``);
    None for ``"gaussian"``."""
    estimator = fitted_estimator(object_noise)
    if estimator is None:
        if model_path is not None:
            raise ConfigError(f"an object noise model ({model_path}) is for object noise {FITTED_PREFIX}NAME, not "
                              f"{GAUSSIAN}")
        return None
    return FittedObjectEstimate(load(model_path or DEFAULT_MODEL), estimator)

"""``hingelab diagnose object-noise-fit``: the fitted model of the camera's object estimate and its residuals.

Reads ``frames.csv`` of ``hingelab diagnose object-estimate`` (every frame's error per estimator), fits
``hingelab.perception.object_noise_model`` on it, and checks the fit by sampling it: per shape, size and
estimator (temporal filters included, run over sampled frames as in the diagnostic), the model's median and
95th percentile of the error's length, its median bias along the ray and its dropout rate beside the measured
ones. Writes ``object_noise_model.json``, ``residuals.csv`` and ``residuals.md``.
"""

from __future__ import annotations

import csv
import hashlib
from pathlib import Path

import numpy as np

from hingelab.errors import ConfigError
from hingelab.perception import object_noise_model as onm
from hingelab.rollouts.reward_diagnostic import write_tables

SAMPLES = 4000  # draws per shape, size and estimator for the residuals
MODEL_FILE = "object_noise_model.json"


def read_frames(path: Path) -> tuple[list[dict], dict]:
    """(the rows of a frames table, its source record: path, sha256, rows); one line if it is missing."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"no frames table at {path}: make one with `hingelab diagnose object-estimate`")
    data = path.read_bytes()
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    return rows, {"path": str(path), "sha256": hashlib.sha256(data).hexdigest(), "rows": len(rows)}


def _measured(rows: list[dict]) -> dict:
    good = [r for r in rows if not r["flag"]]
    err = np.array([float(r["error_mm"]) for r in good])
    ray = np.array([float(r["ray_bias_mm"]) for r in good])
    return {"n": len(rows), "median": np.median(err) if good else np.nan,
            "p95": np.percentile(err, 95) if good else np.nan, "ray": np.median(ray) if good else np.nan,
            "dropout": 1 - len(good) / len(rows) if rows else np.nan}


def _sampled(model: onm.ObjectNoiseModel, estimator: str, shape: str, size: float,
             rng: np.random.Generator, samples: int) -> dict:
    """Errors (mm, ray frame) the model gives: the per-frame draws, or a temporal filter over ``window`` of them."""
    base, window = model.base(estimator)
    params = model.params(base, shape, size)
    if window is None:
        kept = rng.random(samples) >= params["dropout"]
        errors = 1000 * onm.draw_error(params, rng, samples)[kept]
    else:
        # the filter after ``window`` frames (``TemporalFilter``: the per-axis median of the good ones among them)
        frames = 1000 * onm.draw_error(params, rng, samples * window).reshape(samples, window, 3)
        kept = rng.random((samples, window)) >= params["dropout"]
        frames[~kept] = np.nan
        seen = kept.any(axis=1)
        errors = np.nanmedian(frames[seen], axis=1) if seen.any() else np.zeros((0, 3))
    norm = np.linalg.norm(errors, axis=1)
    return {"errors": errors, "median": np.median(norm) if len(norm) else np.nan,
            "p95": np.percentile(norm, 95) if len(norm) else np.nan,
            "ray": np.median(errors[:, 0]) if len(norm) else np.nan,
            "dropout": 1 - len(errors) / samples}


def residuals(rows: list[dict], model: onm.ObjectNoiseModel, seed: int = 0, samples: int = SAMPLES) -> list[dict]:
    """Per shape, size and estimator, and pooled per estimator: measured against the model's sampled median and
    95th percentile of the error (mm), median ray bias (mm, toward the camera) and dropout."""
    out = []
    estimators = list(dict.fromkeys(r["estimator"] for r in rows))
    keys = list(dict.fromkeys((r["shape"], float(r["size_m"])) for r in rows))
    for index, estimator in enumerate(estimators):
        if estimator not in model.estimators:
            continue
        pooled_errors = []
        for key_index, (shape, size) in enumerate(keys):
            group = [r for r in rows
                     if r["estimator"] == estimator and (r["shape"], float(r["size_m"])) == (shape, size)]
            if not group:
                continue
            rng = np.random.default_rng([seed, index, key_index])
            got, want = _sampled(model, estimator, shape, size, rng, samples), _measured(group)
            pooled_errors.append(got["errors"])
            out.append(_row(estimator, shape, size, want, got))
        mine = [r for r in rows if r["estimator"] == estimator]
        errors = np.concatenate(pooled_errors) if pooled_errors else np.zeros((0, 3))
        norm = np.linalg.norm(errors, axis=1)
        got = {"median": np.median(norm), "p95": np.percentile(norm, 95), "ray": np.median(errors[:, 0]),
               "dropout": 1 - len(errors) / (samples * len(pooled_errors))}
        out.append(_row(estimator, "all", "all", _measured(mine), got))
    return out


def _row(estimator: str, shape: str, size, want: dict, got: dict) -> dict:
    r = {"estimator": estimator, "shape": shape, "size_m": size, "frames": want["n"]}
    for name in ("median", "p95", "ray", "dropout"):
        digits = 4 if name == "dropout" else 2
        unit = "" if name == "dropout" else "_mm"
        r[f"measured_{name}{unit}"] = round(float(want[name]), digits)
        r[f"model_{name}{unit}"] = round(float(got[name]), digits)
    r["p95_residual_mm"] = round(r["model_p95_mm"] - r["measured_p95_mm"], 2)
    return r


def write_report(model: dict, table: list[dict], out: Path, command: str, samples: int = SAMPLES) -> Path:
    """``object_noise_model.json``, ``residuals.csv`` and ``residuals.md`` under ``out``; the markdown's path."""
    out = write_tables(out, {"residuals.csv": table})
    onm.save(model, out / MODEL_FILE)
    pooled = [r for r in table if r["shape"] == "all"]
    entries = {e["estimator"]: e for e in model["entries"] if e["shape"] == onm.POOLED}
    lines = [
        "# The fitted model of the camera's object estimate, and its residuals", "",
        f"Made by `{command}`: `hingelab.perception.object_noise_model` fitted on `{model['source'].get('path')}` "
        f"(sha256 {model['source'].get('sha256', '')[:12]}, {model['source'].get('rows')} rows), then sampled "
        f"({samples} draws per shape, size and estimator, seed {model['seed']}; a temporal filter over "
        "sampled frames as the diagnostic ran it) and compared with the measured frames. Errors in mm; the ray "
        "bias is the median error along the viewing ray, positive toward the camera; dropout: the share of "
        "frames without an estimate.", "",
        "## The fit, pooled over shapes and sizes (per-frame estimators; ray frame: toward the camera, right, up)",
        "", "| estimator | bias (mm) | core scale (mm) | outliers | dropout |", "|---|---|---|---|---|"]
    for name, e in entries.items():
        lines.append(f"| {name} | {_vector(e['bias_mm'])} | {_vector(e['scale_mm'])} | {e['outlier_p']:.3f} | "
                     f"{e['dropout']:.4f} |")
    lines += ["", "Temporal filters are not fitted as independent draws: " + (", ".join(
        f"`{k}` runs the median of {v['window']} draws of `{v['of']}`" for k, v in model["filters"].items())
        or "none in the data") + ".", "",
        "## Model against measurement, pooled", "",
        "| estimator | median: measured / model | 95th pct: measured / model | ray bias: measured / model | "
        "dropout: measured / model |", "|---|---|---|---|---|"]
    for r in pooled:
        lines.append(f"| {r['estimator']} | {_cells(r)} |")
    worst = max((r for r in table if r["shape"] != "all"), key=lambda r: abs(r["p95_residual_mm"]))
    lines += ["", f"Largest 95th-percentile residual: {worst['p95_residual_mm']:+.2f} mm ({worst['estimator']}, "
              f"{worst['shape']} {100 * float(worst['size_m']):g} cm).", "",
              "## Per shape and size", "",
              "| estimator | shape | size (cm) | median: measured / model | 95th pct: measured / model | "
              "ray bias: measured / model | dropout: measured / model |", "|---|---|---|---|---|---|---|"]
    for r in table:
        if r["shape"] != "all":
            lines.append(f"| {r['estimator']} | {r['shape']} | {100 * float(r['size_m']):g} | {_cells(r)} |")
    extent = next((e for e in model["entries"] if e.get("extent_bias_mm")), None)
    lines += ["", "The extent (ToolPick-v0's `observe_extent`): " + (
        "fitted per shape and size as the visible bounding box's error per world axis (x, y, z), e.g. the "
        f"pooled {extent['estimator']}: bias {_vector(entries[extent['estimator']]['extent_bias_mm'])} mm, scale "
        f"{_vector(entries[extent['estimator']]['extent_scale_mm'])} mm." if extent else
        "not fitted (the frames table has no extent errors): the env keeps its 2 mm Gaussian."), ""]
    path = out / "residuals.md"
    path.write_text("\n".join(lines))
    return path


def _vector(v) -> str:
    return "n/a" if v is None else "(" + ", ".join(f"{x:+.2f}" for x in v) + ")"


def _cells(r: dict) -> str:
    """The four measured / model cells of a residual row."""
    return (f"{r['measured_median_mm']:.1f} / {r['model_median_mm']:.1f} | "
            f"{r['measured_p95_mm']:.1f} / {r['model_p95_mm']:.1f} | {r['measured_ray_mm']:+.1f} / "
            f"{r['model_ray_mm']:+.1f} | {r['measured_dropout']:.3f} / {r['model_dropout']:.3f}")


def fit_and_report(frames: Path, out: Path, seed: int, command: str, code_version: dict,
                   samples: int = SAMPLES) -> tuple[Path, dict, list]:
    """The whole command: (the markdown's path, the model, the residual rows)."""
    rows, source = read_frames(frames)
    model = onm.fit(rows, source=source, seed=seed, code_version=code_version)
    table = residuals(rows, onm.ObjectNoiseModel(model, str(frames)), seed, samples)
    return write_report(model, table, out, command, samples), model, table

"""How far each object estimator lands from the object's centre: ``hingelab diagnose object-estimate``.

The stand-in's scene (ToolPick-v0's ``tool_pick``, the arm at home in the grasp keyframe, no domain
randomization) with each test shape and size resting upright at ``placements`` random spots of the
placement area (the platform's centre +- ``PLACEMENT_HALF_WIDTH`` in x and y, ToolPick-v0's default).
At each spot the rig's depth camera (``hingelab.sim.rig_camera``) renders ``frames`` frames, each with
fresh depth noise (``DepthNoise()``, the camera path's) and fresh segmentation errors (``MaskErrors()``),
through ``hingelab.perception.object_estimate``: every per-frame estimator on every frame, and the
temporal filter over each estimator's frames at the spot (its estimate after the last frame).

Errors are against the object's true centre (the middle of its resting height, as ToolPick-v0
observes it), in mm: the distance, its component along the viewing ray (the ray from the camera to
the true centre; positive: toward the camera) and across it, and the error's two components across the ray
(``hingelab.perception.object_noise_model.ray_frame``: right and up, so that a fitted model can draw it); per
frame also the visible extent's error against the object's true bounding box along the world axes (the
extent ToolPick-v0 observes, ``observe_extent``). The camera's pose is the true one: a
hand-eye calibration error (``CameraClouds``' per-episode one) is left out here, so the table is the
estimators' own error.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only: works on machines without a display
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from hingelab.camera import AZURE_KINECT_NFOV_UNBINNED, DepthIntrinsics  # noqa: E402
from hingelab.errors import ConfigError  # noqa: E402
from hingelab.perception.object_estimate import (  # noqa: E402
    ESTIMATORS,
    MaskErrors,
    ObjectCloudConfig,
    TemporalFilter,
    estimate_object,
    fit_sphere,
    object_cloud,
)
from hingelab.perception.object_model_fit import ObjectModel  # noqa: E402
from hingelab.perception.object_noise_model import ray_frame  # noqa: E402
from hingelab.rollouts.reward_diagnostic import write_tables  # noqa: E402
from hingelab.sim import scripted  # noqa: E402
from hingelab.sim.core import SimCore  # noqa: E402
from hingelab.sim.depth_noise import DepthNoise  # noqa: E402
from hingelab.sim.object_render import (  # noqa: E402
    ObjectDepthRenderer,
    platform_crop,
    true_object_centre,
    true_object_extent,
)
from hingelab.sim.objects import SHAPES, ObjectSpec  # noqa: E402

SIZES = (0.015, 0.02, 0.025)
PLACEMENT_HALF_WIDTH = 0.05  # m, ToolPick-v0's default
TEMPORAL_WINDOW = 5
PICTURE = ("sphere", 0.02)  # the object of the picture: its first spot's first frame


def errors(estimate: np.ndarray, truth: np.ndarray, camera_position: np.ndarray) -> dict:
    """The error in mm: its length, its component along the ray camera -> truth (positive toward the camera),
    its length across it, and its components across it (``ray_frame``'s right and up)."""
    error = np.asarray(estimate, float) - truth
    toward, right, up = 1000 * (ray_frame(camera_position, truth).T @ error)
    return {"error_mm": 1000 * float(np.linalg.norm(error)), "ray_bias_mm": float(toward),
            "lateral_mm": float(np.hypot(right, up)), "across_right_mm": float(right), "across_up_mm": float(up)}


ERROR_COLUMNS = ("error_mm", "ray_bias_mm", "lateral_mm", "across_right_mm", "across_up_mm")
EXTENT_COLUMNS = ("extent_error_x_mm", "extent_error_y_mm", "extent_error_z_mm")


def measure(placements: int = 20, frames: int = 5, seed: int = 0, shapes=SHAPES, sizes=SIZES,
            intrinsics: DepthIntrinsics = AZURE_KINECT_NFOV_UNBINNED, noise: DepthNoise = DepthNoise(),
            mask_errors: MaskErrors = MaskErrors(), progress: bool = True) -> tuple[list[dict], dict]:
    """(rows: one per frame and per-frame estimator, and one per spot and ``temporal_*`` estimator; the
    picture's data: the first frame at the first spot of ``PICTURE``'s object, or of the first object)."""
    if placements < 1 or frames < 1:
        raise ConfigError(f"give --placements >= 1 and --frames >= 1, not {placements} and {frames}")
    rows, picture = [], {}
    combos = [(shape, size) for shape in shapes for size in sizes]
    bar = tqdm(total=len(combos) * placements * frames, desc="object frames", disable=not progress)
    for index, (shape, size) in enumerate(combos):
        obj = ObjectSpec(shape, size)
        sim = SimCore("tool_pick", obj=obj, camera=intrinsics)
        renderer = ObjectDepthRenderer(sim.model, intrinsics)
        config = ObjectCloudConfig(*platform_crop(sim.model))
        object_model = ObjectModel.from_mujoco(sim.model)
        rng = np.random.default_rng([seed, index])
        for spot in range(placements):
            xy = scripted.platform_center(sim.model) + rng.uniform(-PLACEMENT_HALF_WIDTH, PLACEMENT_HALF_WIDTH, 2)
            sim.reset(seed=int(rng.integers(2**31)), object_xy=xy)
            rendered = renderer.render(sim.data)
            truth = true_object_centre(sim.model, sim.data, obj)
            true_extent = true_object_extent(sim.model, sim.data)
            clean_depth = rendered.frame.depth
            filters = {name: TemporalFilter(TEMPORAL_WINDOW) for name in ESTIMATORS}
            base = {"shape": shape, "size_m": size, "spot": spot, "x_m": round(float(xy[0]), 4),
                    "y_m": round(float(xy[1]), 4)}
            for f in range(frames):
                frame = rendered.frame
                frame.depth = noise.apply(clean_depth, intrinsics, rng)
                mask = mask_errors.apply(rendered.object_mask, rng)
                cloud = object_cloud(frame, mask, config)
                for name in ESTIMATORS:
                    result = estimate_object(frame, mask, name, config, cloud=cloud, object_model=object_model)
                    rows.append(_row(base, f, name, result.estimate, truth, frame.camera_position, cloud,
                                     None if result.extent is None else result.extent - true_extent))
                    filters[name].update(result.estimate)
                if not picture and (spot == 0 and f == 0) and ((shape, size) == PICTURE or PICTURE not in combos):
                    picture = _picture_data(frame, rendered.object_mask, mask, cloud, truth, obj, object_model)
                bar.update()
            for name, filt in filters.items():
                filtered = filt.update(None)
                rows.append(_row(base, frames, f"temporal_{name}", filtered, truth, rendered.frame.camera_position,
                                 None))
        renderer.close()
    bar.close()
    return rows, picture


def _row(base: dict, frame: int, estimator: str, estimate, truth, camera_position, cloud,
         extent_error: np.ndarray | None = None) -> dict:
    """One frame's (or a temporal filter's) row; ``extent_error`` (3,) m, the visible extent's error (None: a
    temporal filter's row, which filters the centre only, or a flagged frame)."""
    row = {**base, "frame": frame, "estimator": estimator, "flag": "" if estimate is not None else
           (cloud.flag if cloud is not None else "no_estimate"),
           "points": 0 if cloud is None or cloud.points is None else len(cloud.points)}
    row.update({k: np.nan for k in ERROR_COLUMNS} if estimate is None else
               {k: round(v, 3) for k, v in errors(estimate, truth, camera_position).items()})
    extent = [np.nan] * 3 if extent_error is None else [round(1000 * float(v), 3) for v in extent_error]
    return {**row, **dict(zip(EXTENT_COLUMNS, extent))}


def summarize(rows: list[dict]) -> list[dict]:
    """Per shape, size and estimator (and "all" shapes and sizes pooled): estimates, flagged, median and 95th
    percentile of the error, median bias along the ray and median error across it (mm)."""
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        for key in ((row["shape"], row["size_m"], row["estimator"]), ("all", "all", row["estimator"])):
            groups.setdefault(key, []).append(row)
    summary = []
    for (shape, size, estimator), group in groups.items():
        good = [r for r in group if r["flag"] == ""]
        err = np.array([r["error_mm"] for r in good])
        bias = np.array([r["ray_bias_mm"] for r in good])
        lateral = np.array([r["lateral_mm"] for r in good])
        stats = {"median_mm": np.median(err), "p95_mm": np.percentile(err, 95), "ray_bias_median_mm":
                 np.median(bias), "lateral_median_mm": np.median(lateral)} if good else {
            "median_mm": np.nan, "p95_mm": np.nan, "ray_bias_median_mm": np.nan, "lateral_median_mm": np.nan}
        summary.append({"shape": shape, "size_m": size, "estimator": estimator, "estimates": len(good),
                        "flagged": len(group) - len(good), **{k: round(float(v), 2) for k, v in stats.items()}})
    return summary


def best_alternative(summary: list[dict]) -> str:
    """The estimator other than the paper's centroid with the lowest pooled 95th percentile."""
    pooled = [s for s in summary if s["shape"] == "all" and s["estimator"] != "centroid" and s["estimates"]]
    return min(pooled, key=lambda s: (s["p95_mm"], s["median_mm"]))["estimator"]


def _picture_data(frame, true_mask, mask, cloud, truth, obj: ObjectSpec, object_model: ObjectModel) -> dict:
    points = cloud.points
    data = {"depth": frame.depth.copy(), "true_mask": true_mask.copy(), "mask": mask.copy(), "points": points,
            "truth": truth.copy(), "camera": np.asarray(frame.camera_position, float).copy(), "object": obj,
            "estimates": {}}
    if points is not None:
        for name, estimator in ESTIMATORS.items():
            data["estimates"][name] = estimator(points, data["camera"], object_model)
        data["sphere_radius"] = fit_sphere(points, data["camera"])[1]
    return data


def write_picture(picture: dict, path: Path) -> Path:
    """One frame: the depth image around the object with the true and the corrupted masks; beside it the
    visible points, the estimates and the true centre seen from the side (the vertical plane of the ray)."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.8))
    v, u = np.nonzero(picture["true_mask"])
    cv, cu, half = int(v.mean()), int(u.mean()), 40
    window = (slice(max(cv - half, 0), cv + half), slice(max(cu - half, 0), cu + half))
    depth = np.where(picture["depth"] > 0, picture["depth"], np.nan)[window]
    left.imshow(depth, cmap=plt.get_cmap("viridis").with_extremes(bad="black"))  # black: no return
    overlay = np.zeros(depth.shape + (4,))
    overlay[picture["mask"][window]] = (1.0, 0.2, 0.2, 0.55)
    left.imshow(overlay)
    left.contour(picture["true_mask"][window], levels=[0.5], colors="white", linewidths=1.0)
    obj = picture["object"]
    left.set_title(f"the {100 * obj.size:g} cm {obj.shape}'s depth (black: no return);\nmask used red, "
                   "true mask white",
                   fontsize=9)
    left.set_xticks([])
    left.set_yticks([])
    truth, camera = picture["truth"], picture["camera"]
    ray = truth - camera
    horizontal = np.array([ray[0], ray[1], 0.0]) / np.linalg.norm(ray[:2])  # away from the camera, level

    def side(p):
        rel = np.atleast_2d(p) - truth
        return 1000 * rel @ horizontal, 1000 * rel[:, 2]

    if picture["points"] is not None:
        right.scatter(*side(picture["points"]), s=6, c="#7f7f7f", label="visible points (after crop, outliers)")
    markers = {"centroid": ("#c8473f", "o"), "ray_corrected": ("#3b7dd8", "s"), "primitive_fit": ("#3aa76d", "D"),
               "mesh_fit": ("#e08a1e", "^")}
    for name, estimate in picture["estimates"].items():
        colour, marker = markers[name]
        right.scatter(*side(estimate), s=60, c=colour, marker=marker, label=name)
    right.scatter(0, 0, s=140, c="black", marker="+", label="true centre")
    half_m = 500 * obj.size
    outline = plt.Circle((0, 0), half_m) if obj.shape == "sphere" else \
        plt.Rectangle((-half_m, -500 * obj.height), 2 * half_m, 1000 * obj.height)
    outline.set(fill=False, ls=":", ec="black", lw=0.8, label="the object's outline")
    right.add_patch(outline)
    down = np.degrees(np.arctan2(-ray[2], np.linalg.norm(ray[:2])))
    right.annotate("", xy=(-half_m * 0.6, half_m * 0.2), xytext=(-half_m * 2.0, half_m * 0.2 + half_m * 1.4 *
                   np.tan(np.radians(down))), arrowprops={"arrowstyle": "->", "color": "#8a63c7"})
    right.text(-half_m * 2.0, half_m * 0.3 + half_m * 1.4 * np.tan(np.radians(down)), "camera ray", fontsize=8,
               color="#8a63c7")
    right.set_xlabel("mm along the ray, level (away from the camera)")
    right.set_ylabel("mm up")
    right.set_aspect("equal")
    right.legend(fontsize=7, loc="lower right")
    right.set_title("side view: the visible points lie on the near side", fontsize=9)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_report(rows: list[dict], summary: list[dict], picture: dict, out: Path, command: str,
                 placements: int, frames: int) -> Path:
    """``frames.csv``, ``summary.csv``, ``object_estimate.md`` and ``frame.png`` under ``out``; the markdown's
    path."""
    out = write_tables(out, {"frames.csv": rows, "summary.csv": summary})
    write_picture(picture, out / "frame.png")
    best = best_alternative(summary)
    order = ["centroid", best] + [name for name in [*ESTIMATORS, *(f"temporal_{n}" for n in ESTIMATORS)]
                                  if name not in ("centroid", best)]
    by_key = {(s["shape"], s["size_m"], s["estimator"]): s for s in summary}
    lines = [
        "# The object's position from the depth camera: each estimator against the truth", "",
        f"Made by `{command}`. The stand-in's scene (arm at home, the object resting upright at {placements} "
        f"random spots of the 10 x 10 cm placement area per shape and size), {frames} frames per spot from the "
        "rig's depth camera with depth noise and segmentation errors; the temporal filters give one estimate "
        f"per spot (the median of the last {TEMPORAL_WINDOW} frames' estimates). Errors against the true centre "
        "(the middle of the resting height), mm; the ray bias is the error's component along the viewing ray, "
        "positive toward the camera. The camera's true pose is used (no calibration error): "
        "`hingelab.rollouts.object_estimate_errors`.", "",
        f"## All shapes and sizes pooled (the paper's centroid, then the best alternative: {best})", "",
        "| estimator | estimates | flagged | median | 95th pct | ray bias (median) | across the ray (median) |",
        "|---|---|---|---|---|---|---|"]
    for name in order:
        s = by_key[("all", "all", name)]
        lines.append(f"| {name} | {s['estimates']} | {s['flagged']} | {s['median_mm']:.1f} | {s['p95_mm']:.1f} | "
                     f"{s['ray_bias_median_mm']:+.1f} | {s['lateral_median_mm']:.1f} |")
    lines += ["", "## Per shape and size: median / 95th percentile (ray bias), mm", "",
              "| shape | size (cm) | " + " | ".join(order) + " |", "|---|---|" + "---|" * len(order)]
    for shape, size in dict.fromkeys((s["shape"], s["size_m"]) for s in summary if s["shape"] != "all"):
        cells = []
        for name in order:
            s = by_key[(shape, size, name)]
            cells.append("flagged" if not s["estimates"] else
                         f"{s['median_mm']:.1f} / {s['p95_mm']:.1f} ({s['ray_bias_median_mm']:+.1f})")
        lines.append(f"| {shape} | {100 * size:g} | " + " | ".join(cells) + " |")
    flags: dict[str, int] = {}
    for row in rows:
        if row["flag"] and not row["estimator"].startswith("temporal_") and row["estimator"] == "centroid":
            flags[row["flag"]] = flags.get(row["flag"], 0) + 1
    lines += ["", "Flagged frames (no estimate), by reason: " +
              (", ".join(f"{k} {v}" for k, v in sorted(flags.items())) if flags else "none") + ".", "",
              "`frame.png`: one frame of the 2 cm sphere, its mask, its points, the estimates and the true centre.", ""]
    path = out / "object_estimate.md"
    path.write_text("\n".join(lines))
    return path

"""Send ``Series`` to a Rerun recording in bulk: one ``send_columns`` call per entity.

Per-step logging (``rec.set_time`` + ``rec.log`` per step) is an order of magnitude slower
(ECOSYSTEM.md); columns let a whole episode, or the same entity of a whole dataset,
go out in one call. Styling that does not change over time (colors, radii, series
names) is logged once as static components of the same entity.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rerun as rr

from hingelab.viewers import entities as E
from hingelab.viewers.episode_series import POINTS2D, POINTS3D, SCALARS, TEXT, TRANSFORM, Series

# RGB colors per entity (the 3-D and plane views), and point radii in metres / plane units
COLORS = {
    E.TOOL_CLOUD: (90, 150, 220), E.TIPS: (230, 60, 60), E.OBJECT: (245, 160, 30),
    E.TARGET: (40, 180, 90), E.PLANE_Z: (90, 150, 220), E.PLANE_Z_GOAL: (40, 180, 90),
}
# Radii: metres in the 3-D view, sized to what they mark: the tips 1.5 mm (the tweezer's pads are
# a few mm), the object the training sphere's 1 cm radius (episodes record the shape, not the size),
# the target a 2.5 mm dot; negative = screen points (Rerun's UI points) on the latent plane.
RADII = {E.TOOL_CLOUD: 0.0012, E.TIPS: 0.0015, E.OBJECT: 0.010, E.TARGET: 0.0025,
         E.PLANE_Z: -6.0, E.PLANE_Z_GOAL: -7.0}
# Labels shown next to the points: the tips are millimetres apart and their labels would sit on each
# other (and on the object's); their names stay in the hover text.
HIDDEN_LABELS = {E.TIPS}
LINE_RADIUS_UI = -1.0  # lines on the latent plane, screen points
TEXT_LEVELS = {"success": "INFO", "failure": "WARN", "attempt": "DEBUG"}


def episode_indexes(series: Series) -> list[rr.TimeColumn]:
    """Timelines of one episode's rows: ``step`` and ``sim_time`` (the log time, exact to the ns)."""
    return [rr.TimeColumn(E.TIMELINE_STEP, sequence=series.step),
            rr.TimeColumn(E.TIMELINE_SIM_TIME, duration=series.time_ns.astype("timedelta64[ns]"))]


def dataset_indexes(episode: np.ndarray, dataset_step: np.ndarray) -> list[rr.TimeColumn]:
    """Timelines of a dataset view's rows: ``episode`` number and ``dataset_step`` (back to back)."""
    return [rr.TimeColumn(E.TIMELINE_EPISODE, sequence=episode),
            rr.TimeColumn(E.TIMELINE_DATASET_STEP, sequence=dataset_step)]


def _level(text: str) -> str:
    return next((level for prefix, level in TEXT_LEVELS.items() if text.startswith(prefix)), "INFO")


def send_series(rec: rr.RecordingStream, series: Series, indexes: Sequence[rr.TimeColumn],
                points_per_row: np.ndarray | None = None) -> None:
    """One ``send_columns`` call for all rows of ``series``.

    points_per_row: (T,) point counts of POINTS3D / POINTS2D rows when they differ per
    row (concatenated episodes with clouds of different sizes); default: values.shape[1].
    """
    values = series.values
    if len(values) == 0:
        return
    if series.kind in (POINTS3D, POINTS2D):
        dim = 3 if series.kind == POINTS3D else 2
        if points_per_row is None:
            points_per_row = np.full(len(values), values.shape[1])
            flat = values.reshape(-1, dim)
        else:
            flat = values
        archetype = rr.Points3D if series.kind == POINTS3D else rr.Points2D
        columns = archetype.columns(positions=flat.astype(np.float32)).partition(points_per_row.tolist())
    elif series.kind == SCALARS:
        columns = rr.Scalars.columns(scalars=values.astype(np.float64))
    elif series.kind == TRANSFORM:
        columns = rr.Transform3D.columns(translation=values[:, :3], quaternion=values[:, 3:7])
    elif series.kind == TEXT:
        texts = [str(t) for t in values]
        columns = rr.TextLog.columns(text=texts, level=[_level(t) for t in texts])
    else:
        raise ValueError(f"unknown series kind {series.kind!r}")
    rec.send_columns(series.entity, indexes=list(indexes), columns=columns)


def send_static_style(rec: rr.RecordingStream, series: Series) -> None:
    """Colors, radii, labels and series names that hold for every row of ``series``."""
    color = COLORS.get(series.entity)
    if series.kind == POINTS3D:
        labels = list(series.names) if series.names and len(series.names) == series.values.shape[1] else None
        rec.log(series.entity, rr.Points3D.from_fields(
            colors=[color] if color else None, radii=[RADII.get(series.entity, 0.002)],
            labels=labels, show_labels=(bool(labels) and series.entity not in HIDDEN_LABELS) if labels else None),
            static=True)
    elif series.kind == POINTS2D:
        rec.log(series.entity, rr.Points2D.from_fields(
            colors=[color] if color else None, radii=[RADII.get(series.entity, -5.0)],
            labels=list(series.names) or None), static=True)
    elif series.kind == SCALARS and series.names:
        rec.log(series.entity, rr.SeriesLines(names=list(series.names)), static=True)


def send_scene_statics(rec: rr.RecordingStream) -> None:
    """hand_base as the 3-D view's frame (metres; +x up: the hand hangs with its x axis up at the pick scene's
    home, tips down, so the platform shows below) and the tool frame's axes."""
    rec.log(E.WORLD, rr.ViewCoordinates.RIGHT_HAND_X_UP, static=True)
    rec.log(E.TOOL_AXES, rr.TransformAxes3D(0.03), static=True)


__all__ = ["send_series", "send_static_style", "send_scene_statics", "episode_indexes", "dataset_indexes",
           "COLORS", "RADII", "LINE_RADIUS_UI", "HIDDEN_LABELS"]

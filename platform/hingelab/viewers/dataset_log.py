"""Log a whole dataset to a Rerun recording: an overview, then every episode back to back.

Overview (from the index alone, no episode is read):

- ``overview/success_by_object`` and ``overview/success_by_source``: bar charts of the
  success rate (0..1), one named bar per object or source (``<chart>/<name>``, a one-value
  ``BarChart`` at its row's position: Rerun's bar charts carry no bar labels, its legend names
  entities), in the order of the ``overview/summary`` tables;
- ``overview/return``, ``overview/length``, ``overview/success``: one value per episode
  on the ``episode`` timeline and, for the episodes the recording holds, on ``dataset_step`` at the
  episode's middle step (the dataset layout opens on ``dataset_step``, so these plots and the
  episodes' series share one timeline, and no point sits on a plot's edge).

Episodes: the same entities as the one-episode view (``entities.py``), all episodes
concatenated per entity and sent in **one** ``send_columns`` call per entity, on the
timelines ``episode`` (to step through episodes) and ``dataset_step`` (all steps back
to back, to replay); the scene's meshes (``robot_log``) are posed every ``cloud_every`` steps.
``overview/latent_plane`` holds every step's z of every episode
(green: successful episodes, red: failed) over the latent plane. Clouds are kept every
``cloud_every`` steps (and at each episode's last step) so a 1000-episode recording
stays small; ``cloud_every=1`` keeps all.
"""

from __future__ import annotations

import time
from collections import defaultdict
from dataclasses import dataclass

import numpy as np
import pandas as pd
import rerun as rr
from tqdm import tqdm

from hingelab.episodes.dataset import Dataset
from hingelab.viewers import entities as E
from hingelab.viewers.episode_series import (
    POINTS2D,
    POINTS3D,
    Series,
    episode_facts_markdown,
    episode_series,
    latent_trajectory,
    tip_midpoints,
)
from hingelab.viewers.rerun_send import (
    COLORS,
    LINE_RADIUS_UI,
    dataset_indexes,
    send_scene_statics,
    send_series,
    send_static_style,
)
from hingelab.viewers.robot_log import DatasetRobot

BAR_COLORS = ((90, 150, 220), (245, 160, 30), (40, 180, 90), (200, 80, 160), (150, 110, 60), (120, 120, 120))
SUCCESS_COLOR = (40, 180, 90)
FAILURE_COLOR = (220, 60, 60)


@dataclass
class DatasetLogStats:
    """What ``log_dataset`` sent: episodes, steps, clouds, and its wall time in seconds."""

    episodes: int
    steps: int
    clouds: int
    read_s: float
    send_s: float


def success_table(index: pd.DataFrame, by: str) -> pd.DataFrame:
    """Episodes, successes and success rate per value of ``by`` (missing values: "(none)")."""
    frame = index.assign(**{by: index[by].fillna("(none)").replace("", "(none)")})
    success = frame["success"].astype("float64")
    table = frame.assign(success=success).groupby(by, sort=True).agg(
        episodes=("success", "size"), successes=("success", "sum"), success_rate=("success", "mean"))
    table["successes"] = table["successes"].astype("int64")
    return table.reset_index()


def _markdown(table: pd.DataFrame, title: str) -> str:
    lines = [f"## {title}", "", "| bar | " + " | ".join(table.columns) + " |",
             "|---" * (len(table.columns) + 1) + "|"]
    for i, row in enumerate(table.itertuples(index=False)):
        cells = [f"{v:.3f}" if isinstance(v, float) else str(v) for v in row]
        lines.append(f"| {i} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def bar_entity(chart: str, name) -> str:
    """The entity of one named bar: ``<chart>/<name>``, so the bar chart's legend names it."""
    return f"{chart}/{rr.escape_entity_path_part(str(name))}"


def log_overview(rec: rr.RecordingStream, dataset: Dataset) -> None:
    """Bar charts and the summary tables (see module doc); the per-episode series: ``log_per_episode``."""
    index = dataset.index
    parts = [f"# {dataset.card.name}: {len(index)} episodes, source {dataset.card.source}\n"]
    for by, entity in (("object", E.SUCCESS_BY_OBJECT), ("source", E.SUCCESS_BY_SOURCE)):
        table = success_table(index, by)
        for i, (name, rate) in enumerate(zip(table[by], table["success_rate"], strict=True)):
            rec.log(bar_entity(entity, name), rr.BarChart([float(rate)], abscissa=[float(i)],
                                                          color=BAR_COLORS[i % len(BAR_COLORS)]), static=True)
        parts.append(_markdown(table, f"success rate by {by} (bar: row)"))
    rec.log(E.SUMMARY, rr.TextDocument("\n".join(parts), media_type="text/markdown"), static=True)


def log_per_episode(rec: rr.RecordingStream, index: pd.DataFrame, middle_steps: np.ndarray | None = None) -> None:
    """Return, length and success of every episode of ``index`` on the ``episode`` timeline; the first
    ``len(middle_steps)`` (the episodes the recording holds) also on ``dataset_step`` at those steps."""
    held = 0 if middle_steps is None else min(len(middle_steps), len(index))
    episode = np.arange(len(index), dtype=np.int64)
    for entity, column, name in ((E.EPISODE_RETURN, "return", "return"), (E.EPISODE_LENGTH, "length", "length"),
                                 (E.EPISODE_SUCCESS, "success", "success")):
        values = index[column].astype("float64").fillna(np.nan).to_numpy()
        rec.log(entity, rr.SeriesPoints(names=[name], marker_sizes=[3.0]), static=True)
        if held:
            rec.send_columns(entity, indexes=dataset_indexes(episode[:held], np.asarray(middle_steps[:held], np.int64)),
                             columns=rr.Scalars.columns(scalars=values[:held]))
        if held < len(index):
            rec.send_columns(entity, indexes=[rr.TimeColumn(E.TIMELINE_EPISODE, sequence=episode[held:])],
                             columns=rr.Scalars.columns(scalars=values[held:]))


class _Concatenator:
    """Collects the same entity's series of many episodes, then sends each entity once."""

    def __init__(self):
        self.rows: dict[tuple, list] = defaultdict(list)  # (entity, kind, trailing shape) -> parts
        self.first: dict[str, Series] = {}
        self.steps = 0

    def add(self, series: Series, episode_number: int, step_offset: int) -> None:
        key = (series.entity, series.kind, series.values.shape[1:] if series.kind not in (POINTS3D, POINTS2D)
               else series.values.shape[2:])
        self.first.setdefault(series.entity, series)
        self.rows[key].append((series.values, np.full(len(series), episode_number, np.int64),
                               series.step + step_offset))

    def send(self, rec: rr.RecordingStream) -> None:
        for series in self.first.values():
            send_static_style(rec, series)
        for (entity, kind, _), parts in self.rows.items():
            episode = np.concatenate([p[1] for p in parts])
            step = np.concatenate([p[2] for p in parts])
            counts = None
            if kind in (POINTS3D, POINTS2D):
                counts = np.concatenate([np.full(len(p[0]), p[0].shape[1], np.int64) for p in parts])
                values = np.concatenate([p[0].reshape(-1, p[0].shape[-1]) for p in parts])
            else:
                values = np.concatenate([p[0] for p in parts])
            merged = Series(entity, kind, values, step, np.zeros(len(step), np.int64))
            send_series(rec, merged, dataset_indexes(episode, step), points_per_row=counts)


def _keep_every(series: Series, every: int) -> Series:
    keep = (series.step % every == 0) | (series.step == series.step[-1])
    return Series(series.entity, series.kind, series.values[keep], series.step[keep], series.time_ns[keep],
                  series.names)


def log_dataset(rec: rr.RecordingStream, dataset: Dataset, cloud_every: int = 10,
                max_episodes: int | None = None, progress: bool = True) -> DatasetLogStats:
    """Overview and all episodes of ``dataset`` (see the module docstring)."""
    started = time.perf_counter()
    send_scene_statics(rec)
    log_overview(rec, dataset)
    paths = dataset.paths()[:max_episodes]
    succeeded = dataset.index["success"].iloc[: len(paths)].fillna(False).to_numpy(bool)
    collected = _Concatenator()
    robot = DatasetRobot(every=cloud_every)  # the scene's meshes, posed at the steps whose clouds are kept
    trajectories, tip_paths, facts, plane_points, plane_colors = [], [], [], [], []
    offset = clouds = 0
    middle_steps = np.zeros(len(paths), np.int64)  # each episode's middle dataset_step (a skipped one: its place)
    for number, path in enumerate(tqdm(paths, desc=f"view {dataset.root.name}", unit="episode",
                                       disable=not progress)):
        middle_steps[number] = offset
        episode = dataset.read_checked(path)
        if episode is None:  # --on-corrupt skip
            continue
        length = 0
        for series in episode_series(episode):
            if len(series) == 0:
                continue
            if series.entity == E.TOOL_CLOUD and cloud_every > 1:
                series = _keep_every(series, cloud_every)
            if series.entity == E.TOOL_CLOUD:
                clouds += len(series)
            collected.add(series, number, offset)
            length = max(length, int(series.step[-1]) + 1)
        z = latent_trajectory(episode)
        trajectories.append(z if z is not None and len(z) > 1 else np.zeros((0, 2)))
        if z is not None:
            plane_points.append(z)
            color = SUCCESS_COLOR if succeeded[number] else FAILURE_COLOR
            plane_colors.append(np.tile(color, (len(z), 1)))
        robot.add(episode, number, offset)
        mid = tip_midpoints(episode)
        tip_paths.append(mid if mid is not None else np.zeros((0, 3)))
        facts.append(episode_facts_markdown(episode))
        middle_steps[number] = offset + max(length - 1, 0) // 2
        offset += length
    read_s = time.perf_counter() - started
    collected.send(rec)
    robot.send(rec)
    log_per_episode(rec, dataset.index, middle_steps)
    first_steps = np.zeros(len(paths), np.int64)  # each episode's first dataset_step
    episode_numbers = np.arange(len(paths), dtype=np.int64)
    if len(paths):
        first_steps = _first_steps(collected, len(paths))
        per_episode = dataset_indexes(episode_numbers, first_steps)
        rec.send_columns(E.FACTS, indexes=per_episode, columns=rr.TextDocument.columns(
            text=facts, media_type=["text/markdown"] * len(facts)))
        rec.send_columns(E.PLANE_TRAJECTORY, indexes=per_episode,
                         columns=rr.LineStrips2D.columns(strips=trajectories))
        rec.log(E.PLANE_TRAJECTORY, rr.LineStrips2D.from_fields(colors=[(150, 150, 150)], radii=[LINE_RADIUS_UI]),
                static=True)
        rec.send_columns(E.TIP_PATH, indexes=per_episode, columns=rr.LineStrips3D.columns(strips=tip_paths))
        rec.log(E.TIP_PATH, rr.LineStrips3D.from_fields(colors=[COLORS[E.TIPS]], radii=[0.0005]), static=True)
    if plane_points:
        rec.log(E.ALL_LATENTS, rr.Points2D(np.concatenate(plane_points), colors=np.concatenate(plane_colors),
                                           radii=[-2.0]), static=True)
    return DatasetLogStats(episodes=len(paths), steps=int(offset), clouds=clouds, read_s=read_s,
                           send_s=time.perf_counter() - started - read_s)


def _first_steps(collected: _Concatenator, n_episodes: int) -> np.ndarray:
    """First ``dataset_step`` of each episode (from the success series, present in every episode)."""
    first = np.zeros(n_episodes, np.int64)
    for (entity, _, _), parts in collected.rows.items():
        if entity == E.SUCCESS:
            for values, episode, step in parts:
                if len(step):
                    first[episode[0]] = step[0]
    return first


__all__ = ["log_dataset", "log_overview", "log_per_episode", "success_table", "bar_entity", "DatasetLogStats"]

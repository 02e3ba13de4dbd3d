"""LeRobot export: a LeRobotDataset v3.0 folder (``LeRobotDataset(repo_id, root=OUT)`` reads it).

Written as LeRobot's own writer does (``lerobot/datasets/lerobot_dataset.py``, ``utils.py``,
codebase v3.0), without LeRobot (it pins an older torch):

    OUT/meta/info.json                          codebase_version "v3.0", fps 20, robot_type, totals,
                                                chunks_size, data_files_size_in_mb, data_path, features
    OUT/meta/stats.json                         per feature: min, max, mean, std, count
    OUT/meta/tasks.parquet                      task string (the index) -> task_index
    OUT/meta/episodes/chunk-000/file-000.parquet  one row per episode (below)
    OUT/data/chunk-000/file-000.parquet         the frames of many episodes; a new file-001 ...
                                                when data_files_size_in_mb (100) would be passed

A frame is one transition k of an episode: ``observation.state`` (the flat observation, or a
goal env's ``observation``) plus ``observation.achieved_goal`` and ``observation.desired_goal``
for a goal env, ``action``, ``next.reward``, ``next.done`` (terminated or truncated: true only at
an episode's last frame), ``next.terminated``, ``next.truncated``, ``next.success`` (false, and
the episode's ``success`` at its last frame), ``info.<name>`` (the scalar infos the step
returned), ``observation.points`` (N, 3) float32 (the tool cloud of the observation, aligned by
log time, NaN where it has none) with ``observation.points_valid``, and LeRobot's
``timestamp`` (frame_index / fps, float32), ``frame_index``, ``episode_index``, ``index``
(contiguous over the dataset) and ``task_index``. Arrays keep their recorded dtype (float64 for
the envs' observations and actions: cast to float32 for a float32 policy).

An episode row: ``episode_index``, ``tasks`` (the episode's ``task``, its gymnasium env id),
``length``, ``data/chunk_index``, ``data/file_index``, ``dataset_from_index``,
``dataset_to_index`` (its ``index`` range), ``meta/episodes/chunk_index``,
``meta/episodes/file_index``, ``stats/<feature>/<stat>``, and hingelab's facts:
``hingelab/episode_id``, ``hingelab/source``, ``hingelab/object``, ``hingelab/seed``,
``hingelab/success``, ``hingelab/return``, ``hingelab/recovered``, ``hingelab/metadata`` (all
metadata, JSON) and ``hingelab/final/<feature>``: the observation after the last action (and its
cloud), which LeRobot's frames have no slot for (null for a recovered episode without one;
such episodes are kept). ``info.json`` also carries ``hingelab``: the dataset card and the env
the episodes were recorded with (id, kwargs, max_episode_steps).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from hingelab.episodes import schemas as S
from hingelab.episodes.card import create_dataset
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.export_output import ExportResult, atomic_folder
from hingelab.episodes.export_source import (
    CONTROL_HZ,
    ExportEpisode,
    ExportLog,
    ExportSchema,
    export_episodes,
    metadata_json,
    recorded_env,
    scan_schema,
    write_back,
)
from hingelab.json_text import strict_dumps
from hingelab.safe_names import safe_relative_path

CODEBASE_VERSION = "v3.0"
ROBOT_TYPE = "jaka_zu7_schunk_svh"
CHUNKS_SIZE = 1000  # files per chunk folder (LeRobot's DEFAULT_CHUNK_SIZE)
DATA_FILE_SIZE_IN_MB = 100  # LeRobot's DEFAULT_DATA_FILE_SIZE_IN_MB
VIDEO_FILE_SIZE_IN_MB = 500
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
OBS_COLUMNS = {"observation": "observation.state", "achieved_goal": "observation.achieved_goal",
               "desired_goal": "observation.desired_goal"}
POINTS = "observation.points"
HIGH_LEVEL_ACTION_NAMES = ["z_goal_0", "z_goal_1", "hand_vx", "hand_vy", "hand_vz"]
DEFAULT_FEATURES = {  # LeRobot's DEFAULT_FEATURES
    "timestamp": {"dtype": "float32", "shape": [1], "names": None},
    "frame_index": {"dtype": "int64", "shape": [1], "names": None},
    "episode_index": {"dtype": "int64", "shape": [1], "names": None},
    "index": {"dtype": "int64", "shape": [1], "names": None},
    "task_index": {"dtype": "int64", "shape": [1], "names": None},
}


def features(schema: ExportSchema) -> dict:
    """info.json ``features``: the frame columns, in file order, with dtype, shape and names."""
    out = {OBS_COLUMNS[k]: {"dtype": f.name, "shape": list(f.shape), "names": None} for k, f in schema.obs.items()}
    names = None
    if schema.action_levels == ["low"] and len(schema.joint_names) == schema.action.shape[0]:
        names = list(schema.joint_names)
    elif schema.action_levels == ["high"] and schema.action.shape == (len(HIGH_LEVEL_ACTION_NAMES),):
        names = list(HIGH_LEVEL_ACTION_NAMES)
    out["action"] = {"dtype": schema.action.name, "shape": list(schema.action.shape), "names": names}
    if schema.points is not None:
        out[POINTS] = {"dtype": "float32", "shape": [schema.points, 3], "names": ["point", "xyz"]}
        out[POINTS + "_valid"] = {"dtype": "bool", "shape": [1], "names": None}
    out["next.reward"] = {"dtype": schema.reward.name, "shape": [1], "names": None}
    for flag in ("next.done", "next.terminated", "next.truncated", "next.success"):
        out[flag] = {"dtype": "bool", "shape": [1], "names": None}
    for name, spec in schema.infos.items():
        out[f"info.{name}"] = {"dtype": spec.name, "shape": [1], "names": None}
    return {**out, **DEFAULT_FEATURES}


def _arrow_type(feature: dict):
    """The arrow type LeRobot's ``get_hf_features_from_features`` gives: Value, fixed-size list, Array2D."""
    value = pa.from_numpy_dtype(np.dtype(feature["dtype"]))
    shape = feature["shape"]
    if shape == [1]:
        return value
    if len(shape) == 1:
        return pa.list_(value, shape[0])
    return pa.list_(pa.list_(value))  # datasets' Array2D storage: nested variable-size lists


def _column(values: np.ndarray, feature: dict, null: np.ndarray | None = None):
    """One column of ``_arrow_type(feature)`` from (rows, *shape) values; ``null``: rows that are null."""
    values = np.ascontiguousarray(values, dtype=feature["dtype"])
    shape = feature["shape"]
    if shape == [1]:
        return pa.array(values.reshape(len(values)))
    if len(shape) == 1:
        return pa.FixedSizeListArray.from_arrays(pa.array(values.reshape(-1)), shape[0])
    rows, inner = len(values), shape[1]
    flat = pa.array(values.reshape(-1))
    points = pa.ListArray.from_arrays(pa.array(np.arange(0, rows * shape[0] * inner + 1, inner, dtype=np.int32)), flat)
    return pa.ListArray.from_arrays(pa.array(np.arange(0, rows * shape[0] + 1, shape[0], dtype=np.int32)), points,
                                    mask=None if null is None else pa.array(null))


def frame_columns(episode: ExportEpisode, episode_index: int, first_index: int, task_index: int) -> dict:
    n = episode.length
    success = np.zeros(n, dtype=bool)
    success[-1] = bool(episode.metadata.get(S.KEY_SUCCESS, False))
    columns = {OBS_COLUMNS[k]: v for k, v in episode.observations.items()}
    columns["action"] = episode.actions
    if episode.points is not None:
        columns[POINTS], columns[POINTS + "_valid"] = episode.points[:n], episode.points_valid[:n]
    columns.update({"next.reward": episode.rewards, "next.done": episode.terminated | episode.truncated,
                    "next.terminated": episode.terminated, "next.truncated": episode.truncated,
                    "next.success": success})
    columns.update({f"info.{name}": v for name, v in episode.infos.items()})
    columns.update({"timestamp": np.arange(n) / CONTROL_HZ, "frame_index": np.arange(n),
                    "episode_index": np.full(n, episode_index), "index": np.arange(first_index, first_index + n),
                    "task_index": np.full(n, task_index)})
    return columns


# --- stats, as LeRobot's compute_episode_stats / aggregate_stats --------------------------------------
def _stats(values: np.ndarray, feature: dict) -> dict | None:
    """min, max, mean, std (the feature's shape; (1, 3) for clouds: per axis) and count, or None.

    Frames with a NaN (no cloud, an info the episode lacks) are left out of the feature's stats.
    """
    values = np.asarray(values, dtype=np.float64).reshape(len(values), *feature["shape"])
    values = values[np.isfinite(values).reshape(len(values), -1).all(axis=1)]
    count = len(values)
    if count == 0:
        return None
    if len(feature["shape"]) == 2:  # clouds: over frames and points, per axis
        values = values.reshape(-1, 1, feature["shape"][1])
    return {"min": values.min(0), "max": values.max(0), "mean": values.mean(0), "std": values.std(0),
            "count": np.array([count])}


def _aggregate(parts: list[dict]) -> dict:
    counts = np.array([p["count"][0] for p in parts], dtype=np.float64)
    weights = counts.reshape(-1, *[1] * parts[0]["mean"].ndim) / counts.sum()
    means = np.stack([p["mean"] for p in parts])
    mean = (weights * means).sum(0)
    variance = (weights * (np.stack([p["std"] for p in parts]) ** 2 + (means - mean) ** 2)).sum(0)
    return {"min": np.min([p["min"] for p in parts], axis=0), "max": np.max([p["max"] for p in parts], axis=0),
            "mean": mean, "std": np.sqrt(variance), "count": np.array([int(counts.sum())])}


def _lists(stats: dict) -> dict:
    return {k: np.asarray(v).tolist() for k, v in stats.items()}


# --- the episode rows ---------------------------------------------------------------------------------
def episode_row(episode: ExportEpisode, episode_index: int, task: str, location: tuple, first_index: int,
                stats: dict) -> dict:
    meta = episode.metadata
    row = {"episode_index": episode_index, "tasks": [task], "length": episode.length,
           "data/chunk_index": location[0], "data/file_index": location[1],
           "dataset_from_index": first_index, "dataset_to_index": first_index + episode.length,
           "meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0}
    for name, values in stats.items():
        for stat, value in _lists(values).items():
            row[f"stats/{name}/{stat}"] = value
    row.update({
        "hingelab/episode_id": meta.get(S.KEY_EPISODE_ID, Path(episode.path).stem),
        "hingelab/source": meta.get(S.KEY_SOURCE), "hingelab/object": meta.get(S.KEY_OBJECT),
        "hingelab/seed": meta.get(S.KEY_SEED) if isinstance(meta.get(S.KEY_SEED), int) else None,
        "hingelab/success": bool(meta.get(S.KEY_SUCCESS, False)),
        "hingelab/return": float(meta[S.KEY_RETURN]) if isinstance(meta.get(S.KEY_RETURN), (int, float)) else None,
        "hingelab/recovered": bool(meta.get(S.KEY_TRUNCATED_FILE, False)),
        "hingelab/metadata": metadata_json(meta),
    })
    for key in episode.observations:
        final = None if episode.final is None else episode.final[key]
        row[f"hingelab/final/{OBS_COLUMNS[key]}"] = None if final is None else np.asarray(final).tolist()
    return row  # the final observation's cloud: a column of its own (export_lerobot)


def _next_file(chunk: int, file: int) -> tuple[int, int]:
    """LeRobot's update_chunk_file_indices."""
    return (chunk + 1, 0) if file == CHUNKS_SIZE - 1 else (chunk, file + 1)


def export_lerobot(dataset, out, data_files_size_in_mb: float = DATA_FILE_SIZE_IN_MB,
                   progress: bool = False) -> ExportResult:
    """Write ``dataset`` as a LeRobotDataset v3.0 folder ``out`` (a new folder)."""
    out = Path(out)
    if out.exists():
        raise DatasetError(f"{out} exists; export into a new folder (or delete that one first)")
    schema = scan_schema(dataset)
    env = recorded_env(dataset, schema)
    feats = features(schema)
    arrow_schema = pa.schema([(name, _arrow_type(f)) for name, f in feats.items()])
    log = ExportLog()
    tasks: dict[str, int] = {}
    rows, all_stats, final_clouds = [], {name: [] for name in feats}, []
    frames, location, writer, file_bytes = 0, (0, 0), None, 0
    with atomic_folder(out) as tmp:
        try:
            for episode in export_episodes(dataset, schema, log, progress, desc="lerobot"):
                log.count(episode, final=False)
                index = len(rows)
                task = episode.metadata.get(S.KEY_TASK) or dataset.card.source
                task_index = tasks.setdefault(task, len(tasks))
                columns = frame_columns(episode, index, frames, task_index)
                table = pa.table({name: _column(columns[name], f) for name, f in feats.items()}, schema=arrow_schema)
                if writer is not None and (file_bytes + table.nbytes) / 2**20 >= data_files_size_in_mb:
                    writer.close()
                    writer, file_bytes, location = None, 0, _next_file(*location)
                if writer is None:
                    path = tmp / DATA_PATH.format(chunk_index=location[0], file_index=location[1])
                    path.parent.mkdir(parents=True, exist_ok=True)
                    writer = pq.ParquetWriter(path, arrow_schema, compression="snappy")
                writer.write_table(table)
                file_bytes += table.nbytes
                stats = {}
                for name, f in feats.items():
                    value = _stats(columns[name], f)
                    if value is not None:
                        stats[name] = value
                        all_stats[name].append(value)
                rows.append(episode_row(episode, index, task, location, frames, stats))
                if episode.points is not None:  # the cloud of the observation after the last action, or NaN
                    final_clouds.append(episode.points[episode.length])
                frames += episode.length
        finally:
            if writer is not None:
                writer.close()
        if not rows:
            raise DatasetError(f"nothing to export from {dataset.root}: every episode was skipped "
                               f"({'; '.join(log.skipped)})")
        meta = tmp / "meta"
        (meta / "episodes" / "chunk-000").mkdir(parents=True)
        keys = list(dict.fromkeys(k for row in rows for k in row))  # every row gets every column (null if absent)
        table = pa.Table.from_pylist([{k: row.get(k) for k in keys} for row in rows])
        if final_clouds:
            clouds = np.stack(final_clouds)
            table = table.append_column(f"hingelab/final/{POINTS}", _column(
                clouds, feats[POINTS], null=~np.isfinite(clouds).all(axis=(1, 2))))
        pq.write_table(table, tmp / EPISODES_PATH.format(chunk_index=0, file_index=0))
        pd.DataFrame({"task_index": list(tasks.values())}, index=list(tasks)).to_parquet(meta / "tasks.parquet")
        stats = {name: _lists(_aggregate(parts)) for name, parts in all_stats.items() if parts}
        (meta / "stats.json").write_text(strict_dumps(stats, meta / "stats.json", indent=4) + "\n")
        card = dataset.card
        info = {
            "codebase_version": CODEBASE_VERSION, "robot_type": ROBOT_TYPE, "total_episodes": len(rows),
            "total_frames": frames, "total_tasks": len(tasks), "chunks_size": CHUNKS_SIZE,
            "data_files_size_in_mb": data_files_size_in_mb, "video_files_size_in_mb": VIDEO_FILE_SIZE_IN_MB,
            "fps": CONTROL_HZ, "splits": {"train": f"0:{len(rows)}"}, "data_path": DATA_PATH, "video_path": None,
            "features": feats,
            "hingelab": {"card": json.loads(card.to_json()), "env": env, "skipped": log.skipped,
                         "notes": log.notes(POINTS)},
        }
        (meta / "info.json").write_text(strict_dumps(info, meta / "info.json", indent=4) + "\n")
    return ExportResult(format="lerobot", path=out, episodes=len(rows), frames=frames, skipped=log.skipped,
                        notes=log.notes(POINTS), load=f"LeRobotDataset(REPO_ID, root={str(out)!r})")


# --- the way back -------------------------------------------------------------------------------------
def _numpy(table, name: str, feature: dict) -> np.ndarray:
    column = table.column(name).combine_chunks()
    shape = feature["shape"]
    if shape == [1]:
        return column.to_numpy(zero_copy_only=False).astype(feature["dtype"])
    flat = column.flatten() if len(shape) == 1 else column.flatten().flatten()
    return flat.to_numpy(zero_copy_only=False).astype(feature["dtype"]).reshape(len(table), *shape)


def import_lerobot(path, root) -> Path:
    """A LeRobot export back into a hingelab dataset at ``root``."""
    path = Path(path)
    info_path = path / "meta" / "info.json"
    if not info_path.is_file():
        raise DatasetError(f"{info_path} is missing: {path} is not a LeRobot dataset folder")
    info = json.loads(info_path.read_text())
    feats = info["features"]
    card = (info.get("hingelab") or {}).get("card") or {"name": path.name, "source": "lerobot", "config": {}}
    create_dataset(root, card["name"], card["source"], card.get("config", {}), card.get("seed"),
                   card.get("description", ""))
    episodes = pq.ParquetDataset(sorted((path / "meta" / "episodes").glob("*/*.parquet"))).read().to_pylist()
    files = {}
    for row in sorted(episodes, key=lambda r: r["episode_index"]):
        key = (row["data/chunk_index"], row["data/file_index"])
        if key not in files:
            files[key] = pq.read_table(path / _data_file(info_path, info, *key))
        table = files[key]
        table = table.filter(pc.equal(table.column("episode_index"), row["episode_index"]))
        table = table.sort_by("frame_index")
        observations = {k: _numpy(table, c, feats[c]) for k, c in OBS_COLUMNS.items() if c in feats}
        finals = {k: row.get(f"hingelab/final/{c}") for k, c in OBS_COLUMNS.items() if c in feats}
        final = (None if any(v is None for v in finals.values())
                 else {k: np.asarray(v, dtype=feats[OBS_COLUMNS[k]]["dtype"]) for k, v in finals.items()})
        points = valid = None
        if POINTS in feats:
            last = row.get(f"hingelab/final/{POINTS}")
            shape = feats[POINTS]["shape"]
            points = np.concatenate([_numpy(table, POINTS, feats[POINTS]),
                                     np.full((1, *shape), np.nan, np.float32) if last is None
                                     else np.asarray(last, np.float32)[None]])
            valid = np.concatenate([_numpy(table, POINTS + "_valid", feats[POINTS + "_valid"]), [last is not None]])
        infos = {n[len("info."):]: _numpy(table, n, feats[n]) for n in feats if n.startswith("info.")}
        terminated = _numpy(table, "next.terminated", feats["next.terminated"])
        write_back(root, json.loads(row.get("hingelab/metadata") or "{}"), observations, final,
                   _numpy(table, "action", feats["action"]), _numpy(table, "next.reward", feats["next.reward"]),
                   terminated, _numpy(table, "next.truncated", feats["next.truncated"]), infos, points, valid)
    return Path(root)


def _data_file(info_path: Path, info: dict, chunk_index, file_index) -> Path:
    """The data file of (chunk, file) by info.json's ``data_path`` template, which must stay inside the dataset."""
    try:
        relative = str(info["data_path"]).format(chunk_index=int(chunk_index), file_index=int(file_index))
    except (KeyError, IndexError, ValueError, AttributeError, TypeError) as exc:
        raise DatasetError(f"{info_path}: data_path {info.get('data_path')!r} is not a LeRobot data path template "
                           f"({type(exc).__name__}: {exc})") from None
    return safe_relative_path(relative, "data_path", info_path)


__all__ = ["export_lerobot", "import_lerobot", "features", "CODEBASE_VERSION"]

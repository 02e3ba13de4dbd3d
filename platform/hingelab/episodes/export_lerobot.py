"""LeRobot export: a LeRobotDataset v3.0 folder (``LeRobotDataset(repo_id, root=OUT)`` reads it).

Written as LeRobot's own writer does (codebase v3.0, checked against LeRobot 0.6.1), without
LeRobot (it pins an older torch):

    OUT/meta/info.json                          codebase_version "v3.0", fps 20, robot_type, totals,
                                                chunks_size, data_files_size_in_mb, data_path, features
                                                (LeRobot's fields only: 0.6 warns about any other)
    OUT/meta/stats.json                         per feature: min, max, mean, std, count, q01, q10, q50,
                                                q90, q99 (``export_stats``)
    OUT/meta/tasks.parquet                      task string (the index) -> task_index
    OUT/meta/episodes/chunk-000/file-000.parquet  one row per episode (below)
    OUT/meta/hingelab.json                      hingelab's facts (below); LeRobot does not read it
    OUT/data/chunk-000/file-000.parquet         the frames of many episodes; a new file-001 ...
                                                when data_files_size_in_mb (100) would be passed

A frame is one transition k of an episode (a trial's frames: ``export_trial``). Every numeric
feature is float32 with a name per dimension (``export_state``):

- ``observation.state``: the flat observation, or a goal env's ``observation`` (plus
  ``observation.achieved_goal`` and ``observation.desired_goal``). ToolPick-v0's Euler angles are
  replaced by the continuous 6-D rotation, and the env's own observation is kept as
  ``env.observation`` (outside ``observation.``: LeRobot's policies do not take it as an input);
- ``action``; ``observation.points`` (N, 3) (the tool cloud of the observation, aligned by log
  time; zeros where it has none) with ``observation.points_valid``;
- ``observation.images.depth`` and ``info.depth_age_s`` when the episodes recorded a depth camera
  (``export_images``: 16-bit millimetres, LeRobot's depth-map convention);
- ``next.reward``, ``next.done`` (terminated or truncated: true only at an episode's last frame),
  ``next.terminated``, ``next.truncated``, ``next.success`` (false, and the episode's ``success``
  at its last frame), ``info.<name>`` (the scalar infos the step returned), and LeRobot's
  ``timestamp`` (frame_index / fps), ``frame_index``, ``episode_index``, ``index`` (contiguous over
  the dataset) and ``task_index``.

No exported value is NaN. A real trial's NaN target is filled by the env's rule
(``export_state.fill_target``); a reward that is NaN in every frame (a source without one: trials,
real imports) and an info with any NaN are left out of the export, each named in the result's
notes and in ``hingelab.json``; a NaN anywhere else (a NaN action, a reward missing in only some
episodes) is one ``DatasetError`` naming the field and the episode.

An episode row: ``episode_index``, ``tasks`` (the episode's ``task``, its gymnasium env id),
``length``, ``data/chunk_index``, ``data/file_index``, ``dataset_from_index``,
``dataset_to_index`` (its ``index`` range), ``meta/episodes/chunk_index``,
``meta/episodes/file_index``, ``stats/<feature>/<stat>``, and hingelab's facts:
``hingelab/episode_id``, ``hingelab/source``, ``hingelab/object``, ``hingelab/seed``,
``hingelab/success``, ``hingelab/return``, ``hingelab/recovered``, ``hingelab/metadata`` (all
metadata, JSON) and ``hingelab/final/<feature>``: the observation after the last action (and its
cloud), which LeRobot's frames have no slot for (null for an episode without one, e.g. a recovered
one or a trial; such episodes are kept). ``meta/hingelab.json``: the dataset card, the env the
episodes were recorded with (id, kwargs, max_episode_steps), the recorded dtypes (for the way
back), what was skipped, filled and left out.
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
from hingelab.episodes.export_images import DEPTH, DEPTH_AGE, depth_feature, depth_shape, episode_depth
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
from hingelab.episodes.export_state import (
    ENV_OBSERVATION,
    StateLayout,
    encode_state,
    fill_target,
    refuse_nan,
    state_layout,
)
from hingelab.episodes.export_stats import aggregate, as_lists, image_stats, vector_stats
from hingelab.episodes.reader import EpisodeFile
from hingelab.json_text import strict_dumps
from hingelab.safe_names import safe_relative_path

CODEBASE_VERSION = "v3.0"
ROBOT_TYPE = "jaka_zu7_schunk_svh"
CHUNKS_SIZE = 1000  # files per chunk folder (LeRobot's DEFAULT_CHUNK_SIZE)
DATA_FILE_SIZE_IN_MB = 100  # LeRobot's DEFAULT_DATA_FILE_SIZE_IN_MB
VIDEO_FILE_SIZE_IN_MB = 500
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
HINGELAB_PATH = "meta/hingelab.json"
OBS_COLUMNS = {"observation": "observation.state", "achieved_goal": "observation.achieved_goal",
               "desired_goal": "observation.desired_goal"}
POINTS = "observation.points"
REWARD = "next.reward"
DEFAULT_FEATURES = {  # LeRobot's DEFAULT_FEATURES
    "timestamp": {"dtype": "float32", "shape": [1], "names": None},
    "frame_index": {"dtype": "int64", "shape": [1], "names": None},
    "episode_index": {"dtype": "int64", "shape": [1], "names": None},
    "index": {"dtype": "int64", "shape": [1], "names": None},
    "task_index": {"dtype": "int64", "shape": [1], "names": None},
}
IMAGE_TYPE = pa.struct([("bytes", pa.binary()), ("path", pa.string())])  # datasets' Image storage


def _float(names: list[str]) -> dict:
    return {"dtype": "float32", "shape": [len(names)], "names": list(names)}


def features(schema: ExportSchema, layout: StateLayout, depth: tuple[int, int] | None = None) -> dict:
    """info.json ``features``: the frame columns, in file order, with dtype, shape and names."""
    out = {"observation.state": _float(layout.state_names())}
    for key in ("achieved_goal", "desired_goal"):
        if key in schema.obs:
            out[OBS_COLUMNS[key]] = _float(layout.names[key])
    if layout.tool_pick:
        out[ENV_OBSERVATION] = _float(layout.names["observation"])
    out["action"] = _float(layout.action)
    if schema.points is not None:
        out[POINTS] = {"dtype": "float32", "shape": [schema.points, 3], "names": ["point", "xyz"]}
        out[POINTS + "_valid"] = {"dtype": "bool", "shape": [1], "names": None}
    if depth is not None:
        out[DEPTH] = depth_feature(depth)
        out[DEPTH_AGE] = {"dtype": "float32", "shape": [1], "names": None}
    out[REWARD] = {"dtype": "float32", "shape": [1], "names": None}
    for flag in ("next.done", "next.terminated", "next.truncated", "next.success"):
        out[flag] = {"dtype": "bool", "shape": [1], "names": None}
    for name in schema.infos:
        out[f"info.{name}"] = {"dtype": "float32", "shape": [1], "names": None}
    return {**out, **DEFAULT_FEATURES}


def _arrow_type(feature: dict):
    """The arrow type LeRobot's ``get_hf_features_from_features`` gives: Value, fixed-size list, Array2D, Image."""
    if feature["dtype"] == "image":
        return IMAGE_TYPE
    value = pa.from_numpy_dtype(np.dtype(feature["dtype"]))
    shape = feature["shape"]
    if shape == [1]:
        return value
    if len(shape) == 1:
        return pa.list_(value, shape[0])
    return pa.list_(pa.list_(value))  # datasets' Array2D storage: nested variable-size lists


def _column(values, feature: dict, null: np.ndarray | None = None):
    """One column of ``_arrow_type(feature)`` from (rows, *shape) values; ``null``: rows that are null."""
    if feature["dtype"] == "image":
        return pa.array(values, type=IMAGE_TYPE)
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


def episode_observations(episode: ExportEpisode, layout: StateLayout, log: ExportLog) -> dict:
    """The observation columns of an episode (target filled, Euler angles re-encoded, NaN refused)."""
    raw = episode.observations["observation"]
    if layout.tool_pick:
        raw, filled = fill_target(episode, raw, episode.infos)
        if filled:
            log.filled.setdefault("observation target (5 cm above the first object position)", []).append(
                Path(episode.path).name)
    columns = {"observation.state": encode_state(raw, layout)}
    for key in ("achieved_goal", "desired_goal"):
        if key in episode.observations:
            columns[OBS_COLUMNS[key]] = episode.observations[key]
    if layout.tool_pick:
        columns[ENV_OBSERVATION] = raw
    for name, values in columns.items():
        refuse_nan(episode, name, values)
    refuse_nan(episode, "action", episode.actions)
    return columns


def frame_columns(episode: ExportEpisode, layout: StateLayout, log: ExportLog, episode_index: int,
                  first_index: int, task_index: int) -> dict:
    n = episode.length
    success = np.zeros(n, dtype=bool)
    success[-1] = bool(episode.metadata.get(S.KEY_SUCCESS, False))
    columns = episode_observations(episode, layout, log)
    columns["action"] = episode.actions
    if episode.points is not None:  # zeros where no cloud: the _valid flag tells
        valid = episode.points_valid[:n]
        columns[POINTS] = np.where(valid[:, None, None], episode.points[:n], np.float32(0))
        columns[POINTS + "_valid"] = valid
    columns.update({REWARD: episode.rewards, "next.done": episode.terminated | episode.truncated,
                    "next.terminated": episode.terminated, "next.truncated": episode.truncated,
                    "next.success": success})
    columns.update({f"info.{name}": v for name, v in episode.infos.items()})
    columns.update({"timestamp": np.arange(n) / CONTROL_HZ, "frame_index": np.arange(n),
                    "episode_index": np.full(n, episode_index), "index": np.arange(first_index, first_index + n),
                    "task_index": np.full(n, task_index)})
    return columns


def _final_columns(episode: ExportEpisode, layout: StateLayout) -> dict:
    """``hingelab/final/<feature>`` of the episode row: the observation after the last action, or None each."""
    keys = [OBS_COLUMNS[k] for k in episode.observations] + ([ENV_OBSERVATION] if layout.tool_pick else [])
    if episode.final is None:
        return {f"hingelab/final/{k}": None for k in keys}
    raw = np.asarray(episode.final["observation"], np.float64)[None]
    values = {"observation.state": encode_state(raw, layout)[0]}
    values.update({OBS_COLUMNS[k]: np.asarray(v) for k, v in episode.final.items() if k != "observation"})
    if layout.tool_pick:
        values[ENV_OBSERVATION] = raw[0]
    return {f"hingelab/final/{k}": (np.asarray(v, np.float32).tolist() if np.isfinite(v).all() else None)
            for k, v in values.items()}


# --- the episode rows ---------------------------------------------------------------------------------
def episode_row(episode: ExportEpisode, layout: StateLayout, episode_index: int, task: str, location: tuple,
                first_index: int, stats: dict) -> dict:
    meta = episode.metadata
    row = {"episode_index": episode_index, "tasks": [task], "length": episode.length,
           "data/chunk_index": location[0], "data/file_index": location[1],
           "dataset_from_index": first_index, "dataset_to_index": first_index + episode.length,
           "meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0}
    for name, values in stats.items():
        for stat, value in as_lists(values).items():
            row[f"stats/{name}/{stat}"] = value
    row.update({
        "hingelab/episode_id": meta.get(S.KEY_EPISODE_ID, Path(episode.path).stem),
        "hingelab/source": meta.get(S.KEY_SOURCE), "hingelab/object": meta.get(S.KEY_OBJECT),
        "hingelab/seed": meta.get(S.KEY_SEED) if isinstance(meta.get(S.KEY_SEED), int) else None,
        "hingelab/success": bool(meta.get(S.KEY_SUCCESS, False)),
        "hingelab/return": (float(meta[S.KEY_RETURN]) if isinstance(meta.get(S.KEY_RETURN), (int, float))
                            and np.isfinite(meta[S.KEY_RETURN]) else None),
        "hingelab/recovered": bool(meta.get(S.KEY_TRUNCATED_FILE, False)),
        "hingelab/metadata": metadata_json(meta),
    })
    row.update(_final_columns(episode, layout))
    return row  # the final observation's cloud: a column of its own (export_lerobot)


def _next_file(chunk: int, file: int) -> tuple[int, int]:
    """LeRobot's update_chunk_file_indices."""
    return (chunk + 1, 0) if file == CHUNKS_SIZE - 1 else (chunk, file + 1)


def _depth_of(dataset, log: ExportLog) -> tuple[int, int] | None:
    """(H, W) of the export's depth images when every episode with frames has a camera, else None (noted)."""
    with_camera, without = [], 0
    for path in dataset.paths():
        with EpisodeFile(path) as episode_file:
            has = S.TOPIC_DEPTH in episode_file.channels
        if has:
            with_camera.append(path)
        else:
            without += 1
    if not with_camera:
        return None
    if without:
        log.left_out[DEPTH] = (f"only {len(with_camera)} of {len(with_camera) + without} episodes recorded a depth "
                               "camera; export those apart to keep their images")
        return None
    return depth_shape(with_camera[0])


def _stats(columns: dict, feats: dict, episode: ExportEpisode, depth) -> dict:
    stats = {}
    for name, f in feats.items():
        if name == DEPTH:
            stats[name] = image_stats(depth.mm[depth.frame_image], episode.length)
            continue
        rows = columns[POINTS + "_valid"] if name == POINTS else None
        value = vector_stats(columns[name], f["shape"], rows)
        if value is not None:
            stats[name] = value
    return stats


def _nan_frames(columns: dict, names) -> dict[str, int]:
    return {name: int(np.isnan(np.asarray(columns[name], np.float64)).sum()) for name in names}


def export_lerobot(dataset, out, data_files_size_in_mb: float = DATA_FILE_SIZE_IN_MB,
                   progress: bool = False) -> ExportResult:
    """Write ``dataset`` as a LeRobotDataset v3.0 folder ``out`` (a new folder)."""
    out = Path(out)
    if out.exists():
        raise DatasetError(f"{out} exists; export into a new folder (or delete that one first)")
    schema = scan_schema(dataset)
    env = recorded_env(dataset, schema)
    log = ExportLog()
    layout = state_layout({k: f.shape for k, f in schema.obs.items()}, int(np.prod(schema.action.shape)),
                          schema.action_levels, schema.joint_names)
    depth_hw = _depth_of(dataset, log)
    feats = features(schema, layout, depth_hw)
    nan_checked = [REWARD, *(f"info.{name}" for name in schema.infos)]
    nan_counts = dict.fromkeys(nan_checked, 0)
    first_nan_reward = None
    arrow_schema = pa.schema([(name, _arrow_type(f)) for name, f in feats.items()])
    tasks: dict[str, int] = {}
    rows, all_stats, final_clouds, files = [], {name: [] for name in feats}, [], []
    frames, location, writer, file_bytes = 0, (0, 0), None, 0
    with atomic_folder(out) as tmp:
        try:
            for episode in export_episodes(dataset, schema, log, progress, desc="lerobot"):
                log.count(episode, final=False)
                index = len(rows)
                task = episode.metadata.get(S.KEY_TASK) or dataset.card.source
                task_index = tasks.setdefault(task, len(tasks))
                columns = frame_columns(episode, layout, log, index, frames, task_index)
                depth = None
                if depth_hw is not None:
                    depth = episode_depth(episode.path, episode.log_time_ns, depth_hw)
                    columns[DEPTH], columns[DEPTH_AGE] = depth.images, depth.age_s
                counts = _nan_frames(columns, nan_checked)
                if counts[REWARD] and first_nan_reward is None:
                    first_nan_reward = Path(episode.path).name
                nan_counts = {k: nan_counts[k] + v for k, v in counts.items()}
                table = pa.table({name: _column(columns[name], f) for name, f in feats.items()}, schema=arrow_schema)
                if writer is not None and (file_bytes + table.nbytes) / 2**20 >= data_files_size_in_mb:
                    writer.close()
                    writer, file_bytes, location = None, 0, _next_file(*location)
                if writer is None:
                    path = tmp / DATA_PATH.format(chunk_index=location[0], file_index=location[1])
                    path.parent.mkdir(parents=True, exist_ok=True)
                    writer = pq.ParquetWriter(path, arrow_schema, compression="snappy")
                    files.append(path)
                writer.write_table(table)
                file_bytes += table.nbytes
                stats = _stats(columns, feats, episode, depth)
                for name, value in stats.items():
                    all_stats[name].append(value)
                rows.append(episode_row(episode, layout, index, task, location, frames, stats))
                if episode.points is not None:  # the cloud of the observation after the last action, or NaN
                    final_clouds.append(episode.points[episode.length])
                frames += episode.length
        finally:
            if writer is not None:
                writer.close()
        if not rows:
            raise DatasetError(f"nothing to export from {dataset.root}: every episode was skipped "
                               f"({'; '.join(log.skipped)})")
        if 0 < nan_counts[REWARD] < frames:
            raise DatasetError(f"{first_nan_reward}: next.reward is NaN while other episodes of {dataset.root} have "
                               "rewards; export the episodes without a reward (trials, real imports) apart")
        dropped = [name for name, count in nan_counts.items() if count]
        for name in dropped:
            log.left_out[name] = ("NaN in every frame: the source records no reward" if name == REWARD else
                                  f"NaN in {nan_counts[name]} of {frames} frames")
        if dropped:
            feats = {k: f for k, f in feats.items() if k not in dropped}
            for path in files:  # written before the whole export was seen: rewritten without those columns
                pq.write_table(pq.read_table(path, columns=list(feats)), path, compression="snappy")
            rows = [{k: v for k, v in row.items() if not any(k.startswith(f"stats/{d}/") for d in dropped)}
                    for row in rows]
        _write_meta(tmp, dataset, env, schema, feats, rows, tasks, all_stats, final_clouds, frames, log,
                    data_files_size_in_mb)
    notes = log.notes(POINTS) + [f"{name} left out: {why}" for name, why in log.left_out.items()]
    return ExportResult(format="lerobot", path=out, episodes=len(rows), frames=frames, skipped=log.skipped,
                        notes=notes, load=f"LeRobotDataset(REPO_ID, root={str(out)!r})")


def _write_meta(tmp: Path, dataset, env, schema: ExportSchema, feats: dict, rows: list, tasks: dict,
                all_stats: dict, final_clouds: list, frames: int, log: ExportLog, data_files_size_in_mb) -> None:
    meta = tmp / "meta"
    (meta / "episodes" / "chunk-000").mkdir(parents=True)
    keys = list(dict.fromkeys(k for row in rows for k in row))  # every row gets every column (null if absent)
    table = pa.Table.from_pylist([{k: row.get(k) for k in keys} for row in rows])
    if final_clouds and POINTS in feats:
        clouds = np.stack(final_clouds)
        table = table.append_column(f"hingelab/final/{POINTS}", _column(
            np.nan_to_num(clouds), feats[POINTS], null=~np.isfinite(clouds).all(axis=(1, 2))))
    pq.write_table(table, tmp / EPISODES_PATH.format(chunk_index=0, file_index=0))
    pd.DataFrame({"task_index": list(tasks.values())}, index=list(tasks)).to_parquet(meta / "tasks.parquet")
    stats = {name: as_lists(aggregate(parts)) for name, parts in all_stats.items() if parts and name in feats}
    (meta / "stats.json").write_text(strict_dumps(stats, meta / "stats.json", indent=4) + "\n")
    info = {
        "codebase_version": CODEBASE_VERSION, "robot_type": ROBOT_TYPE, "total_episodes": len(rows),
        "total_frames": frames, "total_tasks": len(tasks), "chunks_size": CHUNKS_SIZE,
        "data_files_size_in_mb": data_files_size_in_mb, "video_files_size_in_mb": VIDEO_FILE_SIZE_IN_MB,
        "fps": CONTROL_HZ, "splits": {"train": f"0:{len(rows)}"}, "data_path": DATA_PATH, "video_path": None,
        "features": feats,
    }
    (meta / "info.json").write_text(strict_dumps(info, meta / "info.json", indent=4) + "\n")
    recorded = {"observation": schema.obs["observation"].dtype, "action": schema.action.dtype,
                "reward": schema.reward.dtype, **{k: f.dtype for k, f in schema.obs.items()},
                **{f"info.{k}": f.dtype for k, f in schema.infos.items()}}
    facts = {"card": json.loads(dataset.card.to_json()), "env": env, "recorded_dtypes": recorded,
             "skipped": log.skipped, "filled": log.filled, "left_out": log.left_out, "notes": log.notes(POINTS)}
    (tmp / HINGELAB_PATH).write_text(strict_dumps(facts, tmp / HINGELAB_PATH, indent=4) + "\n")


# --- the way back -------------------------------------------------------------------------------------
def _numpy(table, name: str, feature: dict) -> np.ndarray:
    column = table.column(name).combine_chunks()
    shape = feature["shape"]
    if shape == [1]:
        return column.to_numpy(zero_copy_only=False).astype(feature["dtype"])
    flat = column.flatten() if len(shape) == 1 else column.flatten().flatten()
    return flat.to_numpy(zero_copy_only=False).astype(feature["dtype"]).reshape(len(table), *shape)


def import_lerobot(path, root) -> Path:
    """A LeRobot export back into a hingelab dataset at ``root``.

    The env's observation comes from ``env.observation`` where the export re-encoded the state, values
    are cast back to the recorded dtypes (float32 in between: a float64 recording comes back rounded to
    float32), a left-out reward comes back NaN and a cloud-less row (``_valid`` false) NaN again.
    """
    path = Path(path)
    info_path = path / "meta" / "info.json"
    if not info_path.is_file():
        raise DatasetError(f"{info_path} is missing: {path} is not a LeRobot dataset folder")
    info = json.loads(info_path.read_text())
    feats = info["features"]
    facts_path = path / HINGELAB_PATH
    facts = json.loads(facts_path.read_text()) if facts_path.is_file() else (info.get("hingelab") or {})
    dtypes = facts.get("recorded_dtypes") or {}
    card = facts.get("card") or {"name": path.name, "source": "lerobot", "config": {}}
    create_dataset(root, card["name"], card["source"], card.get("config", {}), card.get("seed"),
                   card.get("description", ""))
    episodes = pq.ParquetDataset(sorted((path / "meta" / "episodes").glob("*/*.parquet"))).read().to_pylist()
    columns = {k: c for k, c in OBS_COLUMNS.items() if c in feats}
    if ENV_OBSERVATION in feats:
        columns["observation"] = ENV_OBSERVATION
    files = {}
    for row in sorted(episodes, key=lambda r: r["episode_index"]):
        key = (row["data/chunk_index"], row["data/file_index"])
        if key not in files:
            files[key] = pq.read_table(path / _data_file(info_path, info, *key), columns=[
                name for name, f in feats.items() if f["dtype"] != "image"])
        table = files[key]
        table = table.filter(pc.equal(table.column("episode_index"), row["episode_index"]))
        table = table.sort_by("frame_index")

        def back(name, recorded, column=None):
            values = _numpy(table, column or name, feats[column or name])
            return values.astype(dtypes.get(recorded, values.dtype))

        observations = {k: back(k, k, c) for k, c in columns.items()}
        finals = {k: row.get(f"hingelab/final/{c}") for k, c in columns.items()}
        final = (None if any(v is None for v in finals.values())
                 else {k: np.asarray(v, dtype=dtypes.get(k, feats[columns[k]]["dtype"])) for k, v in finals.items()})
        points = valid = None
        if POINTS in feats:
            last = row.get(f"hingelab/final/{POINTS}")
            shape = feats[POINTS]["shape"]
            valid = np.concatenate([_numpy(table, POINTS + "_valid", feats[POINTS + "_valid"]), [last is not None]])
            points = np.concatenate([_numpy(table, POINTS, feats[POINTS]),
                                     np.full((1, *shape), np.nan, np.float32) if last is None
                                     else np.asarray(last, np.float32)[None]])
            points[~valid] = np.nan
        infos = {n[len("info."):]: back(n, n) for n in feats if n.startswith("info.") and n != DEPTH_AGE}
        n = table.num_rows
        rewards = back(REWARD, "reward") if REWARD in feats else np.full(n, np.nan, dtypes.get("reward", "<f8"))
        write_back(root, json.loads(row.get("hingelab/metadata") or "{}"), observations, final,
                   back("action", "action"), rewards, _numpy(table, "next.terminated", feats["next.terminated"]),
                   _numpy(table, "next.truncated", feats["next.truncated"]), infos, points, valid)
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

"""Export a hingelab dataset to the layouts neighbours use, and import them back.

- Minari (HDF5 layout of Minari datasets): ``OUT/data/main_data.hdf5`` with one group
  ``episode_<i>`` per episode: ``observations`` (T+1 rows, a group of datasets for goal
  envs), ``actions`` (T), ``rewards``, ``terminations``, ``truncations``, ``infos/<name>``;
  the tool clouds as ``tool_points`` (T, N, 3) float32 when present. Root attributes:
  ``dataset_id``, ``total_episodes``, ``total_steps``, ``hingelab_card`` (JSON).
- LeRobot-style parquet (v2 layout): ``OUT/meta/info.json`` (fps, features with dtype
  and shape), ``OUT/meta/episodes.jsonl``, ``OUT/data/chunk-000/episode_<i>.parquet``
  with ``observation.state`` (or ``observation.<key>`` for goal envs), ``action``,
  ``next.reward``, ``next.done``, ``next.terminated``, ``next.truncated``, ``timestamp``,
  ``frame_index``, ``episode_index``, ``index``, ``observation.points`` (fixed-size lists).
  LeRobot has no slot for the observation after the last action: it is kept in
  episodes.jsonl as ``final_observation``.

``import_minari`` and ``import_lerobot`` write a hingelab dataset back (round trip).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from hingelab.episodes import schemas as S
from hingelab.episodes.card import create_dataset
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.transitions import OBS_KEYS
from hingelab.episodes.writer import EpisodeWriter

CONTROL_HZ = 20


def export_dataset(dataset, fmt: str, out) -> Path:
    out = Path(out)
    if out.exists():
        raise DatasetError(f"{out} exists; give --out a new folder name")
    if fmt == "minari":
        return export_minari(dataset, out)
    if fmt == "lerobot":
        return export_lerobot(dataset, out)
    raise DatasetError(f"unknown export format {fmt!r}; choose minari or lerobot")


def _episode_parts(episode):
    step = episode.topics[S.TOPIC_STEP]
    keys = [k for k in OBS_KEYS if k in step]
    points = episode.points if S.TOPIC_POINTS in episode.topics else None
    return step, keys, points


def export_minari(dataset, out: Path) -> Path:
    import h5py

    (out / "data").mkdir(parents=True)
    total = 0
    with h5py.File(out / "data" / "main_data.hdf5", "w") as f:
        for i, episode in enumerate(dataset.iter_episodes(progress=True)):
            step, keys, points = _episode_parts(episode)
            if not all(k in episode.final for k in keys):
                raise DatasetError(f"{episode.path} has no final observation (a recovered episode?); "
                                   "Minari needs T+1 observations: filter it out (recovered=False)")
            group = f.create_group(f"episode_{i}")
            group.attrs.update(id=i, total_steps=len(step["reward"]), seed=episode.metadata.get(S.KEY_SEED, -1),
                               hingelab_metadata=json.dumps(episode.metadata, default=str))
            observations = {k: np.concatenate([step[k], episode.final[k][None]]) for k in keys}
            if keys == ["observation"]:
                group.create_dataset("observations", data=observations["observation"])
            else:
                obs_group = group.create_group("observations")
                for k, v in observations.items():
                    obs_group.create_dataset(k, data=v)
            group.create_dataset("actions", data=step["action"])
            group.create_dataset("rewards", data=step["reward"])
            group.create_dataset("terminations", data=step["terminated"])
            group.create_dataset("truncations", data=step["truncated"])
            infos = group.create_group("infos")
            for name, value in step.items():
                if name.startswith("info."):
                    infos.create_dataset(name[len("info."):], data=value)
            if points is not None:
                group.create_dataset("tool_points", data=points)
            total += len(step["reward"])
        f.attrs.update(dataset_id=dataset.card.name, total_episodes=len(dataset), total_steps=total,
                       hingelab_card=dataset.card.to_json())
    return out


def import_minari(path, root) -> Path:
    """A Minari HDF5 export back into a hingelab dataset at ``root``."""
    import h5py

    from hingelab.episodes.card import DatasetCard

    with h5py.File(Path(path) / "data" / "main_data.hdf5", "r") as f:
        card = DatasetCard(**json.loads(f.attrs["hingelab_card"]))
        create_dataset(root, card.name, card.source, card.config, card.seed, card.description)
        for name in sorted(f, key=lambda n: int(n.split("_")[1])):
            group = f[name]
            meta = json.loads(group.attrs["hingelab_metadata"])
            obs = group["observations"]
            observations = ({k: obs[k][()] for k in obs} if isinstance(obs, h5py.Group) else obs[()])
            infos = {k: v[()] for k, v in group["infos"].items()}
            points = group["tool_points"][()] if "tool_points" in group else None
            _write_back(root, meta, observations, group["actions"][()], group["rewards"][()],
                        group["terminations"][()], group["truncations"][()], infos, points)
    return Path(root)


def export_lerobot(dataset, out: Path) -> Path:
    import pyarrow as pa
    import pyarrow.parquet as pq

    data_dir = out / "data" / "chunk-000"
    data_dir.mkdir(parents=True)
    (out / "meta").mkdir()
    features, episodes_meta, index = {}, [], 0
    for i, episode in enumerate(dataset.iter_episodes(progress=True)):
        step, keys, points = _episode_parts(episode)
        n = len(step["reward"])
        columns = {}
        for k in keys:
            columns["observation.state" if keys == ["observation"] else f"observation.{k}"] = step[k]
        columns["action"] = step["action"]
        if points is not None:
            columns["observation.points"] = points.reshape(n, -1)
        table = {name: pa.FixedSizeListArray.from_arrays(value.reshape(-1), value.shape[1])
                 for name, value in columns.items()}
        table.update({
            "next.reward": pa.array(step["reward"]), "next.terminated": pa.array(step["terminated"]),
            "next.truncated": pa.array(step["truncated"]),
            "next.done": pa.array(step["terminated"] | step["truncated"]),
            "timestamp": pa.array((step["log_time_ns"] - step["log_time_ns"][0]) / 1e9),
            "frame_index": pa.array(np.arange(n)), "episode_index": pa.array(np.full(n, i)),
            "index": pa.array(np.arange(index, index + n)), "task_index": pa.array(np.zeros(n, np.int64)),
        })
        for name, value in step.items():
            if name.startswith("info."):
                table[name] = pa.array(value)
        pq.write_table(pa.table(table), data_dir / f"episode_{i:06d}.parquet", use_dictionary=False)
        for name, value in columns.items():
            features[name] = {"dtype": str(value.dtype), "shape": [int(value.shape[1])]}
        episodes_meta.append({
            "episode_index": i, "length": n, "tasks": [episode.metadata.get(S.KEY_TASK, "")],
            "hingelab_metadata": episode.metadata,
            "final_observation": {k: episode.final[k].tolist() for k in episode.final},
            "final_dtypes": {k: str(episode.final[k].dtype) for k in episode.final},
        })
        index += n
    info = {"codebase_version": "v2.1", "robot_type": "jaka_zu7_svh", "fps": CONTROL_HZ,
            "total_episodes": len(episodes_meta), "total_frames": index, "features": features,
            "data_path": "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet",
            "hingelab_card": json.loads(dataset.card.to_json())}
    (out / "meta" / "info.json").write_text(json.dumps(info, indent=2, default=str) + "\n")
    with open(out / "meta" / "episodes.jsonl", "w") as f:
        for row in episodes_meta:
            f.write(json.dumps(row, default=str) + "\n")
    return out


def import_lerobot(path, root) -> Path:
    """A LeRobot-style export back into a hingelab dataset at ``root``."""
    import pyarrow.parquet as pq

    path = Path(path)
    info = json.loads((path / "meta" / "info.json").read_text())
    card = info["hingelab_card"]
    create_dataset(root, card["name"], card["source"], card["config"], card["seed"], card.get("description", ""))
    rows = [json.loads(line) for line in (path / "meta" / "episodes.jsonl").read_text().splitlines()]
    for row in rows:
        table = pq.read_table(path / "data" / "chunk-000" / f"episode_{row['episode_index']:06d}.parquet")

        def column(name):
            width = info["features"][name]["shape"][0]
            flat = table.column(name).combine_chunks().flatten().to_numpy()
            return flat.reshape(-1, width).astype(info["features"][name]["dtype"])

        final = {k: np.asarray(v, dtype=row["final_dtypes"][k]) for k, v in row["final_observation"].items()}
        if "observation.state" in info["features"]:
            observations = np.concatenate([column("observation.state"), final["observation"][None]])
        else:
            observations = {k: np.concatenate([column(f"observation.{k}"), final[k][None]])
                            for k in OBS_KEYS if f"observation.{k}" in info["features"]}
        points = column("observation.points").reshape(len(table), -1, 3) \
            if "observation.points" in info["features"] else None
        infos = {n[len("info."):]: table.column(n).to_numpy() for n in table.column_names if n.startswith("info.")}
        _write_back(root, row["hingelab_metadata"], observations, column("action"),
                    table.column("next.reward").to_numpy(), table.column("next.terminated").to_numpy(),
                    table.column("next.truncated").to_numpy(), infos, points)
    return Path(root)


def _write_back(root, meta, observations, actions, rewards, terminated, truncated, infos, points) -> None:
    """One episode from stacked arrays (observations with T+1 rows) through EpisodeWriter."""
    n = len(rewards)
    dt = 1.0 / CONTROL_HZ

    def obs_at(k):
        return {key: v[k] for key, v in observations.items()} if isinstance(observations, dict) else observations[k]

    with EpisodeWriter(root, source=meta.get(S.KEY_SOURCE, "imported"), task=meta.get(S.KEY_TASK, ""),
                       object=meta.get(S.KEY_OBJECT, ""), seed=meta.get(S.KEY_SEED),
                       attempt=meta.get(S.KEY_ATTEMPT, 1), config_hash=meta.get(S.KEY_CONFIG_HASH)) as writer:
        for k in range(n):
            writer.write_step(k * dt, points_hand=None if points is None else points[k], transition={
                "observation": obs_at(k), "action": actions[k], "reward": rewards[k],
                "terminated": terminated[k], "truncated": truncated[k],
                "info": {name: v[k] for name, v in infos.items()}})
        writer.write_final_observation(obs_at(n))
        writer.set_outcome(success=bool(meta.get(S.KEY_SUCCESS, False)),
                           failure_reason=meta.get(S.KEY_FAILURE_REASON))


__all__ = ["export_dataset", "export_minari", "export_lerobot", "import_minari", "import_lerobot"]

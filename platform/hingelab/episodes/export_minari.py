"""Minari export: ``minari.load_dataset("NAMESPACE/NAME-vN")`` opens it (Minari 0.5 HDF5 storage).

``--out ROOT`` is a Minari datasets root (what ``MINARI_DATASETS_PATH`` names; it may already
hold other datasets, e.g. ``~/.minari/datasets``). The export writes

    ROOT/NAMESPACE/NAME-vN/data/metadata.json     Minari's dataset attributes
    ROOT/NAMESPACE/NAME-vN/data/main_data.hdf5    one group ``episode_<i>`` per episode
    ROOT/NAMESPACE/namespace_metadata.json        if absent (what ``minari.create_namespace`` writes)

with the dataset id ``hingelab/<dataset folder name>-v0`` unless ``dataset_id`` names another; an
existing ``NAME-vN`` folder is an error (Minari ids are immutable: bump the version).

``metadata.json`` holds what Minari 0.5.4 reads (``minari/dataset/minari_storage.py``,
``minari_dataset.py``): ``dataset_id``, ``total_episodes``, ``total_steps``, ``data_format``
("hdf5"), ``observation_space`` and ``action_space`` serialized like ``minari.serialization``
(Box: type, dtype, shape, low, high; Dict: subspaces), ``env_spec`` (gymnasium's
``EnvSpec.to_json()`` of the env the episodes were recorded with, see
``export_source.recorded_env``; absent when unknown), ``requirements`` (``hingelab>=VERSION``: the
package that registers the env, which ``recover_environment`` checks is installed),
``minari_version``, ``dataset_size``, plus
``algorithm_name`` (the card's source), ``description``, ``code_permalink`` (the writing code's
version and commit) and ``hingelab_card`` (the whole dataset card). Minari is not imported.

Spaces are the env's (``hingelab.tasks.task_spaces``: bounds and dtype, e.g. ToolPick-v0's action
``Box(-1, 1, (5,), float32)``), so offline RL code that scales by the dataset's bounds sees the
env's, and ``dataset.recover_environment()`` gives an env with the same spaces (its
``env_spec`` entry point imports hingelab, which registers the ids). Actions are stored in the
action space's dtype; actions outside its bounds are kept as recorded and counted in the
result's notes. Episodes of no hingelab task (another writer, mixed tasks) keep spaces that
describe the stored arrays: Box(-inf, inf) of the recorded shape and dtype (Dict of
observation, achieved_goal, desired_goal for a goal env), and no ``env_spec``.

An episode group holds ``observations`` (T+1 rows, a group per key for a goal env), ``actions``,
``rewards``, ``terminations``, ``truncations`` (T rows) and ``infos``, which Minari aligns with
the observations (T+1 rows): row 0 is the reset's info, which hingelab does not record (NaN),
row k the info step k-1 returned; ``infos/tool_points`` (T+1, N, 3) float32 is the tool cloud of
each observation (NaN where it has none) and ``infos/tool_points_valid`` (T+1,) says which rows
hold one. Attributes: ``id``, ``total_steps``, ``seed``, ``success`` and ``hingelab_metadata``
(the episode's metadata as JSON; ``dataset.storage.get_episode_metadata([i])`` returns them).

Episodes without a final observation (recovered files) cannot give T+1 observations: they
are skipped and counted in the result.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import gymnasium as gym
import h5py
import numpy as np

from hingelab.episodes import schemas as S
from hingelab.episodes.card import create_dataset
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.export_output import ExportResult, atomic_folder
from hingelab.episodes.export_source import (
    ExportLog,
    ExportSchema,
    Field,
    env_spec_json,
    export_episodes,
    metadata_json,
    recorded_env,
    scan_schema,
    write_back,
)
from hingelab.json_text import strict_dumps
from hingelab.safe_names import safe_file_name
from hingelab.tasks import task_spaces

MINARI_VERSION = "0.5.4"  # the Minari whose reader this layout is written (and tested) for
DEFAULT_NAMESPACE = "hingelab"
NAMESPACE_METADATA = "namespace_metadata.json"
SKIP_NO_FINAL = "no final observation (a recovered episode; Minari needs T+1 observations)"
# minari.dataset.minari_dataset.DATASET_ID_RE with the version required (an id without one fails in its sort key)
DATASET_ID_RE = re.compile(r"^(?:(?P<namespace>[-_\w][-_\w/]*[-_\w]+)/)?(?P<name>[-_\w]+?)-v(?P<version>\d+)$")
POINTS_INFO = "tool_points"


def default_dataset_id(folder_name: str) -> str:
    """``hingelab/<folder name>-v0``, the name made a Minari name (letters, digits, - and _)."""
    name = re.sub(r"[^-\w]+", "_", folder_name)[:100].strip("_-") or "dataset"
    return f"{DEFAULT_NAMESPACE}/{name}-v0"


def check_dataset_id(dataset_id: str) -> str:
    if not DATASET_ID_RE.fullmatch(dataset_id):
        raise DatasetError(f"--dataset-id {dataset_id!r} is not a Minari id; write NAMESPACE/NAME-vN "
                           "(letters, digits, - and _; e.g. hingelab/demo_heuristic-v0)")
    return dataset_id


def _array_box(field: Field) -> gym.spaces.Box:
    return gym.spaces.Box(-np.inf, np.inf, field.shape, np.dtype(field.dtype).newbyteorder("="))


def serialize_space(space: gym.Space) -> dict:
    """A Box or a Dict of Boxes as ``minari.serialization.serialize_space(space, to_string=False)`` writes it."""
    if isinstance(space, gym.spaces.Dict):
        return {"type": "Dict", "subspaces": {k: serialize_space(s) for k, s in space.spaces.items()}}
    return {"type": "Box", "dtype": str(space.dtype), "shape": list(space.shape), "low": space.low.tolist(),
            "high": space.high.tolist()}


def _shapes(space: gym.Space):
    if isinstance(space, gym.spaces.Dict):
        return {k: s.shape for k, s in space.spaces.items()}
    return {"observation": space.shape}


def dataset_spaces(schema: ExportSchema, env: dict | None) -> tuple[gym.Space, gym.Space, str | None]:
    """(observation_space, action_space, why not the env's): the env's spaces when the episodes' task is a
    hingelab task whose spaces have the recorded shapes, else boxes describing the stored arrays."""
    task = task_spaces(env["id"], bool(env["kwargs"].get("observe_extent", False))) if env else None
    if task is None:
        observation = (gym.spaces.Dict({k: _array_box(f) for k, f in schema.obs.items()}) if schema.goal_env
                       else _array_box(schema.obs["observation"]))
        return observation, _array_box(schema.action), None if env is None else f"{env['id']} is no hingelab task"
    observation, action = task
    recorded = {k: f.shape for k, f in schema.obs.items()}
    if _shapes(observation) != recorded or action.shape != schema.action.shape:
        return (dataset_spaces(schema, None)[:2]
                + (f"the episodes' observations {recorded} and actions {schema.action.shape} are not the shapes of "
                   f"{env['id']}'s spaces",))
    return observation, action, None


def spaces(schema: ExportSchema, env: dict | None = None) -> tuple[str, str]:
    """(observation_space, action_space) serialized as ``minari.serialization.serialize_space`` does.

    These strings keep ``Infinity`` for unbounded boxes: that is Minari's own encoding (its ``deserialize_space``
    reads them back with ``json.loads``), and the metadata file that holds them stays strict JSON because they
    are string values in it."""
    observation, action, _ = dataset_spaces(schema, env)
    return json.dumps(serialize_space(observation)), json.dumps(serialize_space(action))


def requirements(card) -> list[str]:
    """Minari's pip-style requirements: the hingelab that wrote the dataset, or a later one."""
    version = str(card.hingelab_version or "")
    return [f"hingelab>={version}" if re.fullmatch(r"\d+(\.\d+)*", version) else "hingelab"]


def _dataset(group, name: str, data: np.ndarray) -> None:
    """Like Minari's writer: chunked and resizable along the steps."""
    group.create_dataset(name, data=data, chunks=True, maxshape=(None, *data.shape[1:]))


def export_minari(dataset, out, dataset_id: str | None = None, progress: bool = False) -> ExportResult:
    """Write ``dataset`` as the Minari dataset ``dataset_id`` under the datasets root ``out``."""
    source = "--dataset-id" if dataset_id else dataset.root
    dataset_id = check_dataset_id(dataset_id or default_dataset_id(dataset.root.name))
    root = Path(out)
    if root.exists() and not root.is_dir():
        raise DatasetError(f"{root} is a file; --out names a Minari datasets folder (MINARI_DATASETS_PATH)")
    parts = dataset_id.split("/")
    final = root.joinpath(*(safe_file_name(part, "the Minari dataset id's part", source,
                                           fix="give --dataset-id NAMESPACE/NAME-vN") for part in parts))
    if final.exists():
        raise DatasetError(f"{final} exists (Minari dataset {dataset_id}); choose another --dataset-id version "
                           f"or another --out")
    schema = scan_schema(dataset)
    env = recorded_env(dataset, schema)
    observation_space, action_space, not_env = dataset_spaces(schema, env)
    if not_env is not None:
        env = None  # recover_environment would give an env whose spaces are not the data's
    action_dtype = action_space.dtype
    log = ExportLog()
    episodes = steps = outside = 0
    with atomic_folder(final) as tmp:
        data_dir = tmp / "data"
        data_dir.mkdir()
        with h5py.File(data_dir / "main_data.hdf5", "w", track_order=True) as f:
            for episode in export_episodes(dataset, schema, log, progress, desc="minari"):
                if episode.final is None:
                    log.skip(episode.path, SKIP_NO_FINAL)
                    continue
                log.count(episode)
                group = f.create_group(f"episode_{episodes}")
                meta = episode.metadata
                attrs = {"id": episodes, "total_steps": episode.length, "success": bool(meta.get(S.KEY_SUCCESS, False)),
                         "hingelab_metadata": metadata_json(meta)}
                if isinstance(meta.get(S.KEY_SEED), int):
                    attrs["seed"] = meta[S.KEY_SEED]
                group.attrs.update(attrs)
                observations = episode.observations_with_final()
                if schema.goal_env:
                    obs_group = group.create_group("observations")
                    for key, value in observations.items():
                        _dataset(obs_group, key, value)
                else:
                    _dataset(group, "observations", observations["observation"])
                actions = episode.actions.astype(action_dtype, copy=False)
                outside += int((~np.all((actions >= action_space.low) & (actions <= action_space.high),
                                        axis=tuple(range(1, actions.ndim)))).sum())
                _dataset(group, "actions", actions)
                _dataset(group, "rewards", episode.rewards)
                _dataset(group, "terminations", episode.terminated)
                _dataset(group, "truncations", episode.truncated)
                infos = group.create_group("infos")
                for name, value in episode.infos.items():
                    _dataset(infos, name, np.concatenate([np.full(1, np.nan, value.dtype), value]))
                if episode.points is not None:
                    _dataset(infos, POINTS_INFO, episode.points)
                    _dataset(infos, POINTS_INFO + "_valid", episode.points_valid)
                episodes += 1
                steps += episode.length
        if episodes == 0:
            raise DatasetError(f"nothing to export from {dataset.root}: every episode was skipped "
                               f"({'; '.join(log.skipped)})")
        card = dataset.card
        metadata = {
            "dataset_id": dataset_id, "total_episodes": episodes, "total_steps": steps, "data_format": "hdf5",
            "jpeg_encoding": False, "observation_space": json.dumps(serialize_space(observation_space)),
            "action_space": json.dumps(serialize_space(action_space)), "requirements": requirements(card),
            "minari_version": MINARI_VERSION, "algorithm_name": card.source,
            "description": card.description or f"hingelab dataset {card.name!r} (source {card.source})",
            "code_permalink": f"hingelab {card.hingelab_version} at git commit {card.git_commit}",
            "hingelab_card": json.loads(card.to_json()),
        }
        notes = log.notes(f"infos/{POINTS_INFO}")
        if outside:
            notes.append(f"{outside} actions lie outside the action space's bounds (kept as recorded)")
        if not_env:
            notes.append(f"spaces describe the stored arrays and no env_spec is written: {not_env}")
        metadata["hingelab_export"] = {"skipped": log.skipped, "notes": notes}
        spec = env_spec_json(env)
        if spec is not None:
            metadata["env_spec"] = spec
        metadata["dataset_size"] = round(sum(p.stat().st_size for p in data_dir.iterdir()) / 1e6, 1)
        (data_dir / "metadata.json").write_text(strict_dumps(metadata, data_dir / "metadata.json"))
    namespace = DATASET_ID_RE.fullmatch(dataset_id).group("namespace")
    if namespace:  # every level, as minari.create_namespace does; an existing one is left alone
        for level in range(1, len(namespace.split("/")) + 1):
            path = root.joinpath(*namespace.split("/")[:level]) / NAMESPACE_METADATA
            if not path.exists():
                path.write_text("{}")
    return ExportResult(
        format="minari", path=final, episodes=episodes, frames=steps, skipped=log.skipped,
        notes=notes + ([] if spec or not_env else ["env_spec unknown (the episodes' task is not one registered "
                                                   "gymnasium env)"]),
        load=f"MINARI_DATASETS_PATH={root} and minari.load_dataset({dataset_id!r})")


def _minari_data_dir(path: Path, dataset_id: str | None) -> Path:
    """The ``data`` folder of a Minari dataset given as its folder, its data folder, or a datasets root."""
    if dataset_id is not None:
        path = path / dataset_id
    for candidate in (path / "data", path):
        if (candidate / "main_data.hdf5").is_file():
            return candidate
    found = sorted(p.parent for p in path.glob("**/data/main_data.hdf5"))
    if len(found) == 1:
        return found[0]
    if not found:
        raise DatasetError(f"{path} holds no Minari dataset (no data/main_data.hdf5); give the folder of an export")
    ids = ", ".join(str(p.parent.relative_to(path)) for p in found)
    raise DatasetError(f"{path} holds several Minari datasets ({ids}); give dataset_id= or the dataset's folder")


def import_minari(path, root, dataset_id: str | None = None) -> Path:
    """A Minari export (its folder, or a datasets root holding it) back into a hingelab dataset at ``root``."""
    data_dir = _minari_data_dir(Path(path), dataset_id)
    metadata = json.loads((data_dir / "metadata.json").read_text()) if (data_dir / "metadata.json").exists() else {}
    card = metadata.get("hingelab_card") or {"name": metadata.get("dataset_id", data_dir.parent.name),
                                             "source": "minari", "config": {}, "seed": None}
    create_dataset(root, card["name"], card["source"], card.get("config", {}), card.get("seed"),
                   card.get("description", ""))
    with h5py.File(data_dir / "main_data.hdf5", "r") as f:
        for name in sorted(f, key=lambda n: int(n.split("_")[1])):
            group = f[name]
            meta = json.loads(group.attrs.get("hingelab_metadata", "{}"))
            obs = group["observations"]
            observations = ({k: obs[k][()] for k in obs} if isinstance(obs, h5py.Group)
                            else {"observation": obs[()]})
            n = len(group["rewards"])
            infos = {k: v[()] for k, v in group["infos"].items()} if "infos" in group else {}
            points, valid = infos.pop(POINTS_INFO, None), infos.pop(POINTS_INFO + "_valid", None)
            if points is not None and valid is None:
                valid = np.isfinite(points).all(axis=(1, 2))
            write_back(root, meta, {k: v[:n] for k, v in observations.items()},
                       {k: v[n] for k, v in observations.items()}, group["actions"][()], group["rewards"][()],
                       group["terminations"][()], group["truncations"][()],
                       {k: v[1:] for k, v in infos.items() if len(v) == n + 1}, points, valid)
    return Path(root)


__all__ = ["export_minari", "import_minari", "default_dataset_id", "check_dataset_id", "dataset_spaces", "requirements",
           "serialize_space", "spaces", "MINARI_VERSION"]

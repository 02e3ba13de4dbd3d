"""What an export takes from each hingelab episode, aligned step by step, and the way back.

One episode becomes ``ExportEpisode``: the ``/step`` arrays (T transitions: observations
before each action, actions, rewards, terminated, truncated, the step's scalar infos), the
final observation (the one after the last action, when the file has it) and the tool clouds
aligned to the T+1 observations.

Topics are not all logged T times, so clouds are aligned deliberately, by log time:

- A file with a *reset record* (messages of any per-step topic logged before the first
  ``/step`` message: what ``RecordingWrapper`` writes at ``reset``, a cloud but no step) logs
  each step's state after the action, at the step's log time. Observation 0 is the reset
  record's, observation k >= 1 the one logged with step k-1, and the final observation the one
  logged with the last step: T steps, T+1 clouds, one per observation.
- A file without one (``write_synthetic_episode``, imports) logs each observation's cloud with
  its own step; the final observation has a cloud only if one is logged after the last step.

Observation k takes the latest cloud logged in (time of observation k-1, time of observation k];
a window without a cloud (a missing cloud) leaves that row NaN and ``points_valid`` false
(never a stale cloud), and a cloud no window takes (an extra cloud) is left out and counted.
Other topics (and any extra topic) are not exported; their message counts do not matter.

A trial (``hingelab trial``, sources ``stand_in`` and ``real``) drives a robot, not an env, and
records no ``/step``: its frames are rebuilt from its topics, one per high-level action
(``export_trial``). Other episodes without ``/step`` transitions are skipped and counted, never
crashed on; the format
modules decide about episodes without a final observation (Minari skips them: it needs T+1
observations; LeRobot keeps them: it has no slot for the final observation anyway).

``write_back`` is the inverse for ``import_minari`` / ``import_lerobot``: stacked arrays back
into an ``EpisodeWriter`` episode (with a reset record when the final observation has a cloud,
so that a re-export aligns the clouds the same way).
"""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np
from gymnasium.envs.registration import load_env_creator
from tqdm import tqdm

from hingelab.episodes import schemas as S
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.export_trial import is_trial, trial_fields, trial_step
from hingelab.episodes.reader import EpisodeFile, read_episode
from hingelab.episodes.writer import EpisodeWriter
from hingelab.json_text import metadata_dumps
from hingelab.tasks import register_envs

OBS_KEYS = ("observation", "achieved_goal", "desired_goal")  # a flat observation, or a goal env's dict
CONTROL_HZ = 20
SKIP_NO_STEPS = "no /step transitions (nothing to export)"
# hingelab metadata an importer gives back to EpisodeWriter as arguments, or that the writer makes itself
_WRITER_KEYS = {
    S.KEY_SOURCE, S.KEY_TASK, S.KEY_OBJECT, S.KEY_SEED, S.KEY_ATTEMPT, S.KEY_CONFIG_HASH, S.KEY_EPISODE_ID,
    S.KEY_SCHEMA_VERSION, S.KEY_START_TIME, S.KEY_END_TIME, S.KEY_CREATED, S.KEY_HINGELAB_VERSION,
    S.KEY_GIT_COMMIT, S.KEY_JOINT_NAMES, S.KEY_ACTION_LEVEL, S.KEY_LENGTH, S.KEY_RETURN, S.KEY_SUCCESS,
    S.KEY_FAILURE_REASON,
}


@dataclass(frozen=True)
class Field:
    dtype: str  # numpy dtype string, e.g. "<f8"
    shape: tuple  # per step

    @property
    def name(self) -> str:  # "float64", "bool", ...
        return np.dtype(self.dtype).name


@dataclass
class ExportSchema:
    """The fields every exported episode has (the union over the dataset, checked for agreement)."""

    obs: dict[str, Field]  # OBS_KEYS present, in that order
    action: Field
    reward: Field
    infos: dict[str, Field]  # scalar infos by name (without "info.")
    points: int | None  # points per cloud, if any episode has clouds
    tasks: list[str]
    action_levels: list[str]
    joint_names: list[str]

    @property
    def goal_env(self) -> bool:
        return list(self.obs) != ["observation"]


@dataclass
class ExportEpisode:
    """One episode's arrays, aligned (see the module docstring)."""

    path: Path
    metadata: dict
    observations: dict[str, np.ndarray]  # (T, ...) each: the observation before each action
    final: dict[str, np.ndarray] | None  # the observation after the last action, or None
    actions: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    infos: dict[str, np.ndarray]  # (T,) each: the info the step returned
    points: np.ndarray | None  # (T+1, N, 3) float32, NaN where no cloud; row T: the final observation's
    points_valid: np.ndarray | None  # (T+1,) bool
    unmatched_clouds: int = 0
    log_time_ns: np.ndarray | None = None  # (T,) the log time of each transition's step

    @property
    def length(self) -> int:
        return len(self.rewards)

    def observations_with_final(self) -> dict[str, np.ndarray]:
        """(T+1, ...) per key; only for episodes with a final observation."""
        return {k: np.concatenate([v, self.final[k][None]]) for k, v in self.observations.items()}


@dataclass
class ExportLog:
    """What was skipped (reason -> file names) and what was noticed on the way."""

    skipped: dict[str, list[str]] = field(default_factory=dict)
    filled: dict[str, list[str]] = field(default_factory=dict)  # what a rule filled -> episode file names
    left_out: dict[str, str] = field(default_factory=dict)  # feature -> why the export left it out
    unmatched_clouds: int = 0
    observations_without_cloud: int = 0

    def skip(self, path: Path, reason: str) -> None:
        self.skipped.setdefault(reason, []).append(Path(path).name)

    def count(self, episode: ExportEpisode, final: bool = True) -> None:
        """Count an exported episode's clouds (``final``: its final observation's too)."""
        self.unmatched_clouds += episode.unmatched_clouds
        if episode.points_valid is not None:
            rows = episode.points_valid if final and episode.final is not None else episode.points_valid[:-1]
            self.observations_without_cloud += int((~rows).sum())

    def notes(self, cloud_slot: str) -> list[str]:
        out = []
        if self.observations_without_cloud:
            out.append(f"{self.observations_without_cloud} observations have no tool cloud ({cloud_slot} is NaN "
                       "there and its _valid flag false)")
        if self.unmatched_clouds:
            out.append(f"{self.unmatched_clouds} tool clouds matched no observation by log time and were left out")
        return out


# --- the schema pass: episode summaries only ---------------------------------------------------
def _file_fields(path: Path) -> tuple[dict, dict | None, int | None]:
    """(metadata, {step field: Field} or None if no transitions, points per cloud or None)."""
    with EpisodeFile(path) as episode_file:
        metadata = episode_file.metadata()
        has_points = S.TOPIC_POINTS in episode_file.channels
        if is_trial(episode_file.channels, metadata):
            point_shapes = episode_file.channel_info(S.TOPIC_POINTS, S.CHANNEL_SHAPES_KEY) if has_points else None
            fields = {name: Field(dtype, shape) for name, (dtype, shape) in trial_fields().items()}
            return metadata, fields, (point_shapes["points"][0] if point_shapes else None)
        if S.TOPIC_STEP not in episode_file.channels:
            return metadata, None, None  # skipped in the data pass, where it is counted
        dtypes = episode_file.channel_info(S.TOPIC_STEP, S.CHANNEL_DTYPES_KEY)
        shapes = episode_file.channel_info(S.TOPIC_STEP, S.CHANNEL_SHAPES_KEY)
        point_shapes = episode_file.channel_info(S.TOPIC_POINTS, S.CHANNEL_SHAPES_KEY) if has_points else None
    if dtypes and shapes and (not has_points or point_shapes):
        fields = {name: Field(dtype, tuple(shapes[name])) for name, dtype in dtypes.items() if name in shapes}
        return metadata, (fields if "reward" in fields else None), (point_shapes["points"][0] if has_points else None)
    # a file from another writer (no dtypes in its channels): read it
    episode = read_episode(path, topics=[S.TOPIC_STEP, S.TOPIC_POINTS])
    step = episode.topics.get(S.TOPIC_STEP, {})
    fields = {name: Field(v.dtype.str, tuple(v.shape[1:])) for name, v in step.items() if name != "log_time_ns"}
    points = episode.topics.get(S.TOPIC_POINTS, {}).get("points")
    n_points = points.shape[1] if points is not None else None
    return metadata, (fields if len(step.get("reward", ())) else None), n_points


def scan_schema(dataset) -> ExportSchema:
    """The export's fields from every episode's summary (no message is read for hingelab's own files).

    Episodes must agree on observation keys, shapes and dtypes (one task per export); infos are
    the union (an episode without one gets NaN).
    """
    paths = dataset.paths()
    if not paths:
        raise DatasetError(f"{dataset.root} has no episodes to export; generate some into it first")
    first, obs_keys, fixed, infos, points = None, None, {}, {}, None
    tasks, levels, joints = [], [], []
    for path in paths:
        metadata, fields, n_points = _file_fields(path)
        if fields is None:
            continue
        keys = [k for k in OBS_KEYS if k in fields]
        if not keys or "action" not in fields:
            raise DatasetError(f"{path}: its /step records have no observation or action; it cannot be exported "
                               "(move it out of episodes/ or filter it out)")
        if obs_keys is None:
            first, obs_keys = path, keys
        elif keys != obs_keys:
            raise DatasetError(f"{path} has observation keys {keys}, {first.name} has {obs_keys}; export one task "
                               "at a time (Dataset(...).filter(task=...))")
        for name in [*keys, "action", "reward", "terminated", "truncated"]:
            if name in fields and fixed.setdefault(name, fields[name]) != fields[name]:
                raise DatasetError(f"{path}: /step {name} is {fields[name].dtype} {fields[name].shape}, in "
                                   f"{first.name} {fixed[name].dtype} {fixed[name].shape}; export one task at a time")
        for name, value in fields.items():
            if name.startswith("info.") and value.shape == ():
                infos.setdefault(name[len("info."):], value)
        if n_points is not None:
            if points is not None and n_points != points:
                raise DatasetError(f"{path} has {n_points}-point clouds, {first.name} {points}-point ones; "
                                   "export datasets with one cloud size")
            points = n_points
        for values, key in ((tasks, S.KEY_TASK), (levels, S.KEY_ACTION_LEVEL)):
            if metadata.get(key) and metadata[key] not in values:
                values.append(metadata[key])
        joints = joints or list(metadata.get(S.KEY_JOINT_NAMES) or [])
    if obs_keys is None:
        raise DatasetError(f"nothing to export: no episode of {dataset.root} has /step transitions")
    return ExportSchema(obs={k: fixed[k] for k in obs_keys}, action=fixed["action"],
                        reward=fixed.get("reward", Field("<f8", ())), infos=infos, points=points, tasks=tasks,
                        action_levels=levels, joint_names=joints)


# --- the data pass -------------------------------------------------------------------------------
def align_clouds(step_times: np.ndarray, reset_time: int | None, cloud_times: np.ndarray,
                 clouds: np.ndarray, n_points: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Clouds for the T+1 observations: (points (T+1, N, 3) NaN where none, valid (T+1,), unmatched)."""
    n = len(step_times)
    if reset_time is not None:  # observation 0 at the reset record, k >= 1 with step k-1, final with step T-1
        obs_times = np.concatenate([[reset_time], step_times]).astype(np.int64)
    else:  # observation k with step k; the final one with a cloud logged after the last step, if any
        obs_times = np.concatenate([step_times, [np.iinfo(np.int64).max]]).astype(np.int64)
    previous = np.concatenate([[np.iinfo(np.int64).min], obs_times[:-1]])
    points = np.full((n + 1, n_points, 3), np.nan, dtype=np.float32)
    valid = np.zeros(n + 1, dtype=bool)
    if len(cloud_times) == 0:
        return points, valid, 0
    order = np.argsort(cloud_times, kind="stable")
    cloud_times, clouds = np.asarray(cloud_times)[order], clouds[order]
    latest = np.searchsorted(cloud_times, obs_times, side="right") - 1  # latest cloud at or before
    valid = latest >= 0
    valid[valid] = cloud_times[latest[valid]] > previous[valid]  # ... and after the previous observation
    points[valid] = clouds[latest[valid]]
    return points, valid, len(cloud_times) - len(np.unique(latest[valid]))


def _reset_time(episode, first_step_ns: int) -> int | None:
    """Log time of the reset record: the latest message of any other topic before the first step."""
    latest = None
    for topic, fields in episode.topics.items():
        if topic in (S.TOPIC_STEP, S.TOPIC_COLUMNS):
            continue
        times = np.asarray(fields.get("log_time_ns", ()), dtype=np.int64)
        earlier = times[times < first_step_ns]
        if len(earlier):
            latest = int(earlier.max()) if latest is None else max(latest, int(earlier.max()))
    return latest


def align_episode(episode, schema: ExportSchema) -> ExportEpisode | str:
    """The episode's export arrays, or the reason it is skipped."""
    step = episode.topics.get(S.TOPIC_STEP, {})
    if not step and is_trial(episode.topics, episode.metadata):
        step = trial_step(episode)
    n = len(step.get("reward", ()))
    if n == 0:
        return SKIP_NO_STEPS
    for name in [*schema.obs, "action", "reward"]:
        if name not in step:
            raise DatasetError(f"{episode.path}: its /step records have no {name!r}; export one task at a time")
    fields = {**schema.obs, "action": schema.action, "reward": schema.reward}
    arrays = {}
    for name, spec in fields.items():
        value = np.asarray(step[name])
        if value.shape != (n, *spec.shape):
            raise DatasetError(f"{episode.path}: /step {name} has shape {value.shape[1:]}, the dataset's other "
                               f"episodes {spec.shape}; export one task at a time")
        arrays[name] = value.astype(spec.dtype, copy=False)
    final = ({k: np.asarray(episode.final[k]).astype(schema.obs[k].dtype, copy=False) for k in schema.obs}
             if all(k in episode.final for k in schema.obs) else None)
    false = np.zeros(n, dtype=bool)
    infos = {name: np.asarray(step.get("info." + name, np.full(n, np.nan)), dtype=spec.dtype)
             for name, spec in schema.infos.items()}
    points = valid = None
    unmatched = 0
    if schema.points is not None:
        cloud = episode.topics.get(S.TOPIC_POINTS)
        times = np.asarray(cloud["log_time_ns"], dtype=np.int64) if cloud else np.zeros(0, dtype=np.int64)
        clouds = cloud["points"] if cloud else np.zeros((0, schema.points, 3), dtype=np.float32)
        step_times = np.asarray(step["log_time_ns"], dtype=np.int64)
        points, valid, unmatched = align_clouds(step_times, _reset_time(episode, int(step_times[0])), times,
                                                clouds, schema.points)
    return ExportEpisode(
        path=episode.path, metadata=episode.metadata, observations={k: arrays[k] for k in schema.obs}, final=final,
        actions=arrays["action"], rewards=arrays["reward"],
        terminated=np.asarray(step.get("terminated", false), dtype=bool),
        truncated=np.asarray(step.get("truncated", false), dtype=bool),
        infos=infos, points=points, points_valid=valid, unmatched_clouds=unmatched,
        log_time_ns=np.asarray(step["log_time_ns"], dtype=np.int64))


def export_episodes(dataset, schema: ExportSchema, log: ExportLog, progress: bool = False,
                    desc: str = "export") -> Iterator[ExportEpisode]:
    """Every episode of ``dataset`` aligned (skipped ones go to ``log``), one at a time."""
    for path in tqdm(dataset.paths(), desc=f"{desc} {dataset.root.name}", unit="episode", disable=not progress):
        episode = dataset.read_checked(path)
        if episode is None:  # --on-corrupt skip
            log.skip(path, "cannot be read (corrupt; --on-corrupt skip)")
            continue
        item = align_episode(episode, schema)
        if isinstance(item, str):
            log.skip(path, item)
            continue
        yield item  # the format module calls log.count() for the episodes it writes


# --- the environment the episodes were recorded with ---------------------------------------------------
def _constructor_parameters(entry_point: str) -> set[str]:
    """Parameter names of an env class's constructor (imports its module), or none if it cannot load."""
    try:
        return set(inspect.signature(load_env_creator(entry_point)).parameters)
    except (ImportError, AttributeError, ValueError, TypeError):
        return set()


def recorded_env(dataset, schema: ExportSchema) -> dict | None:
    """{"id", "kwargs", "max_episode_steps"} of the gymnasium env the episodes were recorded with, or None.

    The id is the episodes' ``task`` when all share one registered gymnasium id. The keyword
    arguments come from the dataset card's config: its entries named like a parameter of the
    env's constructor (``hingelab generate heuristic``: object, size, mass, randomize), then its
    ``env`` and ``env_kwargs`` objects (``hingelab eval low``, ``hingelab train low``);
    ``max_episode_steps`` is the time limit of ``gymnasium.make``. None when the task is not a
    registered env (another writer) or the episodes mix tasks.
    """
    if len(schema.tasks) != 1:
        return None
    register_envs()
    env_id = schema.tasks[0]
    if env_id not in gym.registry:
        return None
    spec = gym.registry[env_id]
    config = dataset.card.config if isinstance(dataset.card.config, dict) else {}
    parameters = _constructor_parameters(spec.entry_point) if isinstance(spec.entry_point, str) else set()
    kwargs = {k: v for k, v in config.items() if k in parameters and v is not None}
    for key in ("env", "env_kwargs"):
        if isinstance(config.get(key), dict):
            kwargs.update(config[key])
    limit = kwargs.pop("max_episode_steps", config.get("max_episode_steps", spec.max_episode_steps))
    return {"id": env_id, "kwargs": dict(spec.kwargs or {}, **kwargs),
            "max_episode_steps": int(limit) if isinstance(limit, (int, float)) else None}


def env_spec_json(env: dict | None) -> str | None:
    """gymnasium's ``EnvSpec.to_json()`` of ``recorded_env``'s result (what Minari stores), or None."""
    if env is None:
        return None
    spec = dataclasses.replace(gym.registry[env["id"]], kwargs=env["kwargs"],
                               max_episode_steps=env["max_episode_steps"])
    try:
        return spec.to_json()
    except (TypeError, ValueError):  # kwargs JSON cannot hold: no spec rather than a wrong one
        return None


# --- the way back ----------------------------------------------------------------------------------
def write_back(root, meta: dict, observations: dict[str, np.ndarray], final: dict[str, np.ndarray] | None,
               actions, rewards, terminated, truncated, infos: dict[str, np.ndarray],
               points: np.ndarray | None = None, points_valid: np.ndarray | None = None) -> Path:
    """One episode from stacked arrays (``observations`` T rows, clouds T+1 rows) through EpisodeWriter."""
    n = len(rewards)
    dt = 1.0 / CONTROL_HZ
    flat = list(observations) == ["observation"]

    def observation(k):
        return observations["observation"][k] if flat else {key: v[k] for key, v in observations.items()}

    def cloud(k):
        return None if points is None or not points_valid[k] else points[k]

    reset_record = points is not None and bool(points_valid[n])  # the final observation has a cloud
    extra = {k: v for k, v in meta.items() if k not in _WRITER_KEYS and v is not None}
    with EpisodeWriter(root, source=meta.get(S.KEY_SOURCE, "imported"), task=meta.get(S.KEY_TASK, ""),
                       object=meta.get(S.KEY_OBJECT, ""), seed=meta.get(S.KEY_SEED),
                       attempt=meta.get(S.KEY_ATTEMPT, 1), config_hash=meta.get(S.KEY_CONFIG_HASH),
                       action_level=meta.get(S.KEY_ACTION_LEVEL) or "",
                       joint_names=meta.get(S.KEY_JOINT_NAMES) or S.SVH_JOINT_NAMES,
                       extra_metadata=extra) as writer:
        if reset_record:
            writer.write_step(0.0, points_hand=cloud(0))
        for k in range(n):
            writer.write_step((k + reset_record) * dt, points_hand=cloud(k + reset_record), transition={
                "observation": observation(k), "action": actions[k], "reward": rewards[k],
                "terminated": bool(terminated[k]), "truncated": bool(truncated[k]),
                "info": {name: v[k] for name, v in infos.items()}})
        if final is not None:
            writer.write_final_observation(final["observation"] if flat else final)
        writer.set_outcome(success=bool(meta.get(S.KEY_SUCCESS, False)), failure_reason=meta.get(S.KEY_FAILURE_REASON))
    return writer.path


def metadata_json(metadata: dict) -> str:
    return metadata_dumps(metadata)


__all__ = ["ExportEpisode", "ExportLog", "ExportSchema", "Field", "OBS_KEYS", "align_clouds", "align_episode",
           "env_spec_json", "export_episodes", "recorded_env", "scan_schema", "write_back"]

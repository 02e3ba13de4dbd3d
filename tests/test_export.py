"""``hingelab datasets export``: Minari and LeRobot v3 exports of the platform's own datasets load in
their own readers (Minari itself; LeRobot's layout read back with pyarrow), clouds are aligned by
log time, odd episodes are handled deliberately, and a failed export leaves nothing behind."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from hingelab.cli.main import main
from hingelab.episodes import EpisodeWriter, create_dataset, export_source
from hingelab.episodes import schemas as S
from hingelab.episodes.dataset import Dataset
from hingelab.episodes.export import export_dataset, export_lerobot, export_minari
from hingelab.episodes.export_minari import SKIP_NO_FINAL
from hingelab.episodes.export_source import SKIP_NO_STEPS, align_clouds
from hingelab.episodes.recover import recover_episode
from hingelab.episodes.synthetic import synthetic_step

DT = 0.05
STEPS = 6  # per episode: the suite stays fast


# --- datasets from the platform's own generators (small) ----------------------------------------------
@pytest.fixture(scope="module")
def heuristic(tmp_path_factory):
    """ToolPick-v0, the privileged heuristic (``hingelab generate heuristic``)."""
    from hingelab.rollouts.heuristic_demos import HeuristicRunConfig, generate_heuristic_dataset

    root = tmp_path_factory.mktemp("heuristic") / "heuristic"
    generate_heuristic_dataset(root, HeuristicRunConfig(episodes=2, seed=3, max_episode_steps=STEPS), progress=False)
    return root


def _run(env, seeds, action_dim):
    rng = np.random.default_rng(0)
    for seed in seeds:
        env.reset(seed=seed)
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(rng.uniform(-1, 1, action_dim).astype(np.float32))
            done = terminated or truncated
    env.close()


@pytest.fixture(scope="module")
def low_eval(tmp_path_factory):
    """ToolShape-v0 (goal env, Dict observations), as ``hingelab eval low`` records it."""
    from hingelab.rollouts.low_level import make_eval_env

    root = tmp_path_factory.mktemp("low_eval") / "low_eval"
    env_args = {"randomize": False, "max_episode_steps": STEPS}
    create_dataset(root, name="eval-low", source="low_level_evaluation", config={"episodes": 2, "env": env_args},
                   seed=0)
    _run(make_eval_env(env_args, record_dir=root), (11, 12), 9)
    return root


@pytest.fixture(scope="module")
def low_train(tmp_path_factory):
    """ToolShape-v0 training rollouts, as ``hingelab train low`` records them."""
    from hingelab.learners.sac.low_level_config import LowLevelTrainConfig
    from hingelab.training.envs import _make_training_env

    root = tmp_path_factory.mktemp("low_train") / "low_train"
    config = LowLevelTrainConfig(max_episode_steps=STEPS, n_envs=1, randomize=False)
    create_dataset(root, name="run-rollouts", source=config.train_source,
                   config={k: v for k, v in config.to_dict().items() if k != "steps"}, seed=0)
    _run(_make_training_env(LowLevelTrainConfig, config.to_dict(), str(root), 0), (None, None), 9)
    return root


@pytest.fixture(scope="module")
def pick_random(tmp_path_factory):
    """ToolPick-v0 recorded by RecordingWrapper with another policy (the future high-level data)."""
    from hingelab.envs import TOOL_PICK_ID
    from hingelab.envs.recording import RecordingWrapper

    root = tmp_path_factory.mktemp("pick") / "pick"
    create_dataset(root, name="pick-random", source="high_level_evaluation",
                   config={"object": "cube", "max_episode_steps": 4}, seed=0)
    env = RecordingWrapper(gym.make(TOOL_PICK_ID, object="cube", max_episode_steps=4), root,
                           source="high_level_evaluation", object_name="cube", action_level="high")
    _run(env, (5,), 5)
    return root


# --- a dataset of odd episodes, written with EpisodeWriter ----------------------------------------------
def _recorded_like(root, seed, n, missing_cloud=None, extra_cloud_after=None):
    """A reset record then n steps (each step's state logged after its action), like RecordingWrapper,
    with one cloud left out (``missing_cloud``: the observation index) or one extra cloud in between;
    /tool/latent is logged at every other step only. Returns (observations (n+1), clouds (n+1, NaN if none))."""
    rng = np.random.default_rng(seed)
    steps = [synthetic_step(rng, k, n + 1) for k in range(n + 1)]
    observations = np.stack([s["transition"]["observation"] for s in steps])
    clouds = np.stack([s["points_hand"] for s in steps])
    with EpisodeWriter(root, source="stand_in", task="stand_in/edge", object="cube", seed=seed,
                       action_level="low") as writer:
        writer.write_step(0.0, points_hand=clouds[0], latent_z=steps[0]["latent_z"])
        for k in range(n):
            transition = dict(steps[k]["transition"], truncated=k == n - 1)
            writer.write_step((k + 1) * DT, transition=transition,
                              points_hand=None if missing_cloud == k + 1 else clouds[k + 1],
                              latent_z=steps[k]["latent_z"] if k % 2 else None)
            if extra_cloud_after == k:
                writer.write_step((k + 1.5) * DT, points_hand=clouds[k + 1] + 1.0)
        writer.write_final_observation(observations[n])
        writer.set_outcome(success=seed % 2 == 0)
    if missing_cloud is not None:
        clouds[missing_cloud] = np.nan
    return observations, clouds


@pytest.fixture(scope="module")
def edge(tmp_path_factory):
    root = tmp_path_factory.mktemp("edge") / "edge"
    create_dataset(root, name="edge", source="stand_in", config={}, seed=0)
    expected = {0: _recorded_like(root, 0, 5, missing_cloud=3), 1: _recorded_like(root, 1, 4, extra_cloud_after=1)}
    with EpisodeWriter(root, source="synthetic", task="stand_in/edge") as writer:  # clouds only, no /step
        writer.write_step(0.0, points_hand=np.zeros((256, 3), np.float32))
    # a writer killed mid-episode, recovered: no final observation
    rng = np.random.default_rng(2)
    with pytest.raises(RuntimeError):
        with EpisodeWriter(root, source="stand_in", task="stand_in/edge", object="cube", seed=2,
                           flush_every_steps=2, keep_partial_on_error=True) as writer:
            for k in range(5):
                step = synthetic_step(rng, k, 5)
                writer.write_step(k * DT, points_hand=step["points_hand"], transition=step["transition"])
            raise RuntimeError("killed")
    partial = next((root / "episodes").glob("*.partial"))
    recover_episode(partial, root / "episodes" / "stand_in-recovered.mcap")
    partial.unlink()
    return root, expected


# --- readers -------------------------------------------------------------------------------------------
def load_minari(root, dataset_id, monkeypatch):
    import minari

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    return minari.load_dataset(dataset_id)


def minari_episodes(dataset):
    """[(EpisodeData, hingelab metadata)]"""
    episodes = list(dataset.iterate_episodes())
    metas = list(dataset.storage.get_episode_metadata(range(len(episodes))))
    return [(e, json.loads(m["hingelab_metadata"])) for e, m in zip(episodes, metas)]


def lerobot_tables(out):
    info = json.loads((out / "meta" / "info.json").read_text())
    data = pq.ParquetDataset(sorted((out / "data").glob("*/*.parquet"))).read()
    episodes = pq.read_table(out / "meta" / "episodes" / "chunk-000" / "file-000.parquet").to_pylist()
    return info, data, episodes


def column(table, name):
    """A frame column as numpy: scalars (T,), vectors (T, D), clouds (T, N, 3)."""
    col = table.column(name).combine_chunks()
    import pyarrow as pa

    if pa.types.is_fixed_size_list(col.type):
        return col.flatten().to_numpy().reshape(len(col), -1)
    if pa.types.is_list(col.type):
        return np.asarray(col.to_pylist(), dtype=np.float32)
    return col.to_numpy(zero_copy_only=False)


def source_episodes(root):
    return {ep.metadata["episode_id"]: ep for ep in Dataset(root)}


# --- the platform's datasets -----------------------------------------------------------------------------
ENVS = {  # fixture: (env id, observation shapes, action shape)
    "heuristic": ("hingelab/ToolPick-v0", {"observation": (14,)}, (5,)),
    "low_eval": ("hingelab/ToolShape-v0", {"observation": (26,), "achieved_goal": (2,), "desired_goal": (2,)}, (9,)),
    "low_train": ("hingelab/ToolShape-v0", {"observation": (26,), "achieved_goal": (2,), "desired_goal": (2,)}, (9,)),
    "pick_random": ("hingelab/ToolPick-v0", {"observation": (14,)}, (5,)),
}


def expected_env_kwargs(name, root):
    config = Dataset(root).card.config
    if name == "heuristic":
        keys = ("object", "size", "mass", "randomize", "object_noise")  # what the config records and the env takes
        return {k: config[k] for k in keys if k in config}, config["max_episode_steps"]
    if name == "low_eval":
        return {"randomize": False}, STEPS
    if name == "low_train":
        from hingelab.learners.sac.low_level_config import LowLevelTrainConfig

        arguments = LowLevelTrainConfig.from_dict({**config, "steps": 1}).env_arguments()
        return {k: v for k, v in arguments.items() if k != "max_episode_steps"}, STEPS
    return {"object": "cube"}, 4


@pytest.mark.parametrize("name", list(ENVS))
def test_minari_export_loads_in_minari_equal_to_the_source(name, request, tmp_path, monkeypatch):
    root = request.getfixturevalue(name)
    result = export_minari(Dataset(root), tmp_path / "minari")
    dataset_id = f"hingelab/{root.name}-v0"  # the dataset folder's name
    assert result.path == tmp_path / "minari" / dataset_id and not result.skipped
    loaded = load_minari(tmp_path / "minari", dataset_id, monkeypatch)
    env_id, obs_shapes, action_shape = ENVS[name]
    space = loaded.observation_space
    if len(obs_shapes) > 1:
        assert isinstance(space, gym.spaces.Dict) and {k: s.shape for k, s in space.spaces.items()} == obs_shapes
    else:
        assert isinstance(space, gym.spaces.Box) and space.shape == obs_shapes["observation"]
    assert loaded.action_space.shape == action_shape
    kwargs, limit = expected_env_kwargs(name, root)
    assert loaded.env_spec.id == env_id and loaded.env_spec.kwargs == kwargs
    assert loaded.env_spec.max_episode_steps == limit
    source = source_episodes(root)
    episodes = minari_episodes(loaded)
    assert len(episodes) == len(source) == loaded.total_episodes
    assert loaded.total_steps == sum(len(ep[S.TOPIC_STEP]["reward"]) for ep in source.values())
    for data, meta in episodes:
        original = source[meta["episode_id"]]
        step, n = original[S.TOPIC_STEP], len(original[S.TOPIC_STEP]["reward"])
        for key in obs_shapes:
            got = data.observations[key] if len(obs_shapes) > 1 else data.observations
            np.testing.assert_array_equal(got, np.concatenate([step[key], original.final[key][None]]))
        np.testing.assert_array_equal(data.actions, step["action"].astype(np.float32))  # the env's dtype
        np.testing.assert_array_equal(data.rewards, step["reward"])
        np.testing.assert_array_equal(data.terminations, step["terminated"])
        np.testing.assert_array_equal(data.truncations, step["truncated"])
        assert np.isnan(data.infos["is_success"][0])  # the reset's info: not recorded
        np.testing.assert_array_equal(data.infos["is_success"][1:], step["info.is_success"])
        # RecordingWrapper: the reset's cloud and one per step, T+1 clouds for T+1 observations
        assert len(original.points) == n + 1 and data.infos["tool_points_valid"].all()
        np.testing.assert_array_equal(data.infos["tool_points"], original.points)
        assert meta["success"] == original.metadata["success"]
    if name == "low_eval":  # the env comes back from the spec, with the spaces the data has
        env = loaded.recover_environment()
        assert {k: s.shape for k, s in env.observation_space.spaces.items()} == obs_shapes
        env.close()


@pytest.mark.parametrize("name", list(ENVS))
def test_lerobot_export_has_the_v3_layout_and_the_source_frames(name, request, tmp_path):
    root = request.getfixturevalue(name)
    out = tmp_path / "lerobot"
    result = export_lerobot(Dataset(root), out)
    info, data, episodes = lerobot_tables(out)
    source = source_episodes(root)
    lengths = {eid: len(ep[S.TOPIC_STEP]["reward"]) for eid, ep in source.items()}
    assert info["codebase_version"] == "v3.0" and info["fps"] == 20 and info["robot_type"]
    assert info["total_episodes"] == len(source) == len(episodes) == result.episodes
    assert info["total_frames"] == sum(lengths.values()) == data.num_rows == result.frames
    assert info["data_path"] == "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
    assert info["chunks_size"] == 1000 and info["data_files_size_in_mb"] == 100 and info["total_tasks"] == 1
    assert list(info["features"]) == data.column_names  # every column is a feature, in file order
    assert all({"dtype", "shape", "names"} <= set(f) for f in info["features"].values())
    env_id, obs_shapes, action_shape = ENVS[name]
    tool_pick = env_id == "hingelab/ToolPick-v0"  # its Euler angles become the 6-D rotation; env.observation as is
    raw = "env.observation" if tool_pick else "observation.state"
    assert info["features"][raw]["shape"] == list(obs_shapes["observation"])
    assert info["features"]["observation.state"]["shape"] == [obs_shapes["observation"][0] + 3 * tool_pick]
    assert info["features"]["action"]["shape"] == list(action_shape)
    assert info["features"]["observation.points"]["shape"] == [256, 3]
    assert "hingelab" not in info  # LeRobot 0.6 warns about unknown fields: hingelab's facts are a file of their own
    assert json.loads((out / "meta" / "hingelab.json").read_text())["env"]["id"] == env_id
    tasks = pd.read_parquet(out / "meta" / "tasks.parquet")
    assert tasks.loc[env_id, "task_index"] == 0
    np.testing.assert_array_equal(column(data, "index"), np.arange(data.num_rows))  # contiguous
    stats = json.loads((out / "meta" / "stats.json").read_text())
    for feature in ("observation.state", "action", "next.reward"):
        assert set(stats[feature]) == {"min", "max", "mean", "std", "count", "q01", "q10", "q50", "q90", "q99"}
        assert stats[feature]["count"] == [data.num_rows]
    np.testing.assert_allclose(stats["action"]["mean"], column(data, "action").mean(0), rtol=1e-5)
    for row in episodes:
        original = source[row["hingelab/episode_id"]]
        step = original[S.TOPIC_STEP]
        n = lengths[row["hingelab/episode_id"]]
        assert row["length"] == n and row["tasks"] == [env_id]
        assert (row["data/chunk_index"], row["data/file_index"]) == (0, 0)
        frames = data.slice(row["dataset_from_index"], row["dataset_to_index"] - row["dataset_from_index"])
        assert (column(frames, "episode_index") == row["episode_index"]).all()
        np.testing.assert_array_equal(column(frames, "frame_index"), np.arange(n))
        np.testing.assert_allclose(column(frames, "timestamp"), np.arange(n) / 20, atol=1e-6)
        f32 = np.float32
        np.testing.assert_array_equal(column(frames, raw), step["observation"].astype(f32))
        np.testing.assert_array_equal(column(frames, "action"), step["action"].astype(f32))
        np.testing.assert_array_equal(column(frames, "next.reward"), step["reward"].astype(f32))
        done = column(frames, "next.done")
        assert done[-1] and not done[:-1].any()
        success = column(frames, "next.success")
        assert success[-1] == original.metadata["success"] and not success[:-1].any()
        np.testing.assert_array_equal(column(frames, "observation.points"), original.points[:n])
        assert column(frames, "observation.points_valid").all()
        np.testing.assert_array_equal(np.asarray(row[f"hingelab/final/{raw}"], f32),
                                      original.final["observation"].astype(f32))
        np.testing.assert_array_equal(np.asarray(row["hingelab/final/observation.points"], np.float32),
                                      original.points[n])
        if len(obs_shapes) > 1:
            np.testing.assert_array_equal(column(frames, "observation.desired_goal"), step["desired_goal"].astype(f32))


def test_lerobot_rolls_over_to_new_data_files(heuristic, low_eval, tmp_path):
    out = tmp_path / "lerobot"
    export_lerobot(Dataset(low_eval), out, data_files_size_in_mb=0.01)  # ~40 KB per episode: one file each
    info, data, episodes = lerobot_tables(out)
    files = sorted((out / "data" / "chunk-000").glob("*.parquet"))
    assert [f.name for f in files] == [f"file-{i:03d}.parquet" for i in range(len(episodes))]
    for row in episodes:
        frames = pq.read_table(out / info["data_path"].format(chunk_index=row["data/chunk_index"],
                                                              file_index=row["data/file_index"]))
        index = column(frames, "index")
        assert index[0] == row["dataset_from_index"] and index[-1] + 1 == row["dataset_to_index"]
        assert (column(frames, "episode_index") == row["episode_index"]).all()


# --- odd episodes -----------------------------------------------------------------------------------------
def test_align_clouds_by_log_time():
    steps = np.array([50, 100, 150])
    clouds = np.arange(4, dtype=np.float32)[:, None, None] * np.ones((1, 2, 3), np.float32)
    points, valid, unmatched = align_clouds(steps, 0, np.array([0, 50, 100, 150]), clouds, 2)  # a reset record
    assert valid.all() and unmatched == 0 and points[:, 0, 0].tolist() == [0, 1, 2, 3]
    points, valid, unmatched = align_clouds(steps, 0, np.array([0, 50, 75, 80]), clouds, 2)  # two in one window
    assert valid.tolist() == [True, True, True, False] and unmatched == 1  # the one at 75 is left out
    assert points[2, 0, 0] == 3 and np.isnan(points[3]).all()  # the latest since observation 1; none after 100
    points, valid, unmatched = align_clouds(steps, None, np.array([50, 100, 150]), clouds[:3], 2)  # no reset record
    assert valid.tolist() == [True, True, True, False] and points[:3, 0, 0].tolist() == [0, 1, 2]


def test_odd_episodes_are_exported_deliberately(edge, tmp_path, monkeypatch, capsys):
    root, expected = edge
    result = export_minari(Dataset(root), tmp_path / "minari")
    assert len(result.skipped[SKIP_NO_STEPS]) == 1 and result.skipped[SKIP_NO_FINAL] == ["stand_in-recovered.mcap"]
    assert any("1 tool clouds matched no observation" in n for n in result.notes)
    assert any("1 observations have no tool cloud" in n for n in result.notes)
    loaded = load_minari(tmp_path / "minari", "hingelab/edge-v0", monkeypatch)
    assert loaded.env_spec is None  # "stand_in/edge" is no gymnasium env
    episodes = minari_episodes(loaded)
    assert len(episodes) == 2
    for data, meta in episodes:
        observations, clouds = expected[meta["seed"]]
        np.testing.assert_array_equal(data.observations, observations)
        np.testing.assert_array_equal(data.infos["tool_points"], clouds)  # NaN where the cloud is missing
        np.testing.assert_array_equal(data.infos["tool_points_valid"], np.isfinite(clouds).all(axis=(1, 2)))
    out = tmp_path / "lerobot"
    result = export_lerobot(Dataset(root), out)
    assert list(result.skipped) == [SKIP_NO_STEPS] and result.episodes == 3  # LeRobot keeps the recovered one
    info, data, episodes = lerobot_tables(out)
    recovered = [row for row in episodes if row["hingelab/recovered"]]
    assert len(recovered) == 1 and recovered[0]["hingelab/final/observation.state"] is None
    assert column(data, "next.done").sum() == 3
    for row in episodes:
        if row["hingelab/seed"] in expected:
            frames = data.slice(row["dataset_from_index"], row["length"])
            observations, clouds = expected[row["hingelab/seed"]]
            valid = np.isfinite(clouds[:-1]).all(axis=(1, 2))
            np.testing.assert_array_equal(column(frames, "observation.points_valid"), valid)
            np.testing.assert_array_equal(column(frames, "observation.points"), np.where(  # no NaN: zeros, not valid
                valid[:, None, None], clouds[:-1], 0))
            np.testing.assert_array_equal(column(frames, "observation.state"), observations[:-1].astype(np.float32))
    # the CLI says what was skipped
    assert main(["datasets", "export", str(root), "--format", "minari", "--out", str(tmp_path / "m2")]) == 0
    printed = capsys.readouterr().out
    assert "Exported 2 episodes" in printed and "skipped 1 (no final observation" in printed
    assert "MINARI_DATASETS_PATH=" in printed and "hingelab/edge-v0" in printed


# --- failures --------------------------------------------------------------------------------------------
def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("hingelab: error: "), err
    return err[0]


@pytest.mark.parametrize("fmt", ["minari", "lerobot"])
def test_a_failed_export_leaves_nothing_behind(edge, fmt, tmp_path, monkeypatch):
    root, _ = edge
    calls = []

    def fail_on_the_second(episode, schema):
        calls.append(episode.path)
        if len(calls) == 2:
            raise RuntimeError("disk full")
        return real(episode, schema)

    real = export_source.align_episode
    monkeypatch.setattr(export_source, "align_episode", fail_on_the_second)
    out = tmp_path / "nested" / "out"
    with pytest.raises(RuntimeError, match="disk full"):
        export_dataset(Dataset(root), fmt, out)
    assert len(calls) == 2  # it failed midway, with files written
    assert not (tmp_path / "nested").exists()  # nor the parents it made
    assert list(tmp_path.iterdir()) == []


def test_corrupt_episode_and_existing_out_are_one_line_errors(low_eval, tmp_path, capsys):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(low_eval, copy)
    (copy / "index.parquet").unlink(missing_ok=True)
    good = sorted((copy / "episodes").glob("*.mcap"))[0]
    (copy / "episodes" / "zz-cut.mcap").write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    for fmt in ("minari", "lerobot"):
        assert main(["datasets", "export", str(copy), "--format", fmt, "--out", str(tmp_path / fmt)]) == 1
        line = _one_line_error(capsys)
        assert "zz-cut.mcap" in line and "recover" in line
        assert not (tmp_path / fmt).exists()
    for fmt, existing in (("minari", tmp_path / "m" / "hingelab" / "low_eval-v0"), ("lerobot", tmp_path / "l")):
        existing.mkdir(parents=True)
        out = tmp_path / fmt[0]
        assert main(["datasets", "export", str(low_eval), "--format", fmt, "--out", str(out)]) == 1
        assert "exists" in _one_line_error(capsys)
    assert main(["datasets", "export", str(low_eval), "--format", "minari", "--out", str(tmp_path / "m"),
                 "--dataset-id", "no-version"]) == 1
    assert "NAMESPACE/NAME-vN" in _one_line_error(capsys)
    assert main(["datasets", "export", str(low_eval), "--format", "minari", "--out", str(tmp_path / "m"),
                 "--dataset-id", "lab/eval-v3"]) == 0
    assert (tmp_path / "m" / "lab" / "eval-v3" / "data" / "metadata.json").exists()
    assert (tmp_path / "m" / "lab" / "namespace_metadata.json").exists()


def test_recorded_round_trip_through_both_formats(low_eval, tmp_path):
    """import_minari / import_lerobot give back the recorded episodes, clouds and final observations."""
    from hingelab.episodes.export import import_lerobot, import_minari

    source = source_episodes(low_eval)
    export_minari(Dataset(low_eval), tmp_path / "m")
    export_lerobot(Dataset(low_eval), tmp_path / "l")
    for back in (import_minari(tmp_path / "m", tmp_path / "mb"), import_lerobot(tmp_path / "l", tmp_path / "lb")):
        copies = {ep.metadata["seed"]: ep for ep in Dataset(back)}
        assert len(copies) == len(source)
        lerobot = back.name == "lb"  # LeRobot's features are float32: a float64 recording comes back rounded

        def rounded(value):
            value = np.asarray(value)
            return value.astype(np.float32).astype(value.dtype) if lerobot and value.dtype.kind == "f" else value

        for original in source.values():
            copy = copies[original.metadata["seed"]]
            for key, value in original[S.TOPIC_STEP].items():
                if key != "log_time_ns":
                    np.testing.assert_array_equal(copy[S.TOPIC_STEP][key], rounded(value))
                    # Minari keeps the env's action space (float32): the policy's float32 actions come back exact
                    minari_action = not lerobot and key == "action"
                    assert copy[S.TOPIC_STEP][key].dtype == (np.float32 if minari_action else value.dtype)
            np.testing.assert_array_equal(copy.points, original.points)
            for key in original.final:
                np.testing.assert_array_equal(copy.final[key], rounded(original.final[key]))
            assert copy.metadata["success"] == original.metadata["success"]

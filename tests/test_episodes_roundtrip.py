"""Episodes written by EpisodeWriter read back bit-exact, and decode without hingelab."""

from __future__ import annotations

import numpy as np
import pytest

from hingelab.episodes import DatasetError, EpisodeWriter, codec, create_dataset, read_episode
from hingelab.episodes import schemas as S
from hingelab.episodes.synthetic import CONTROL_DT_S, write_synthetic_episode

N_STEPS = 40


@pytest.fixture
def dataset(tmp_path):
    create_dataset(tmp_path / "ds", name="test", source="synthetic", config={"k": 1}, seed=0)
    return tmp_path / "ds"


def _stack(steps, getter):
    return np.stack([np.asarray(getter(s)) for s in steps])


def test_every_topic_reads_back_bit_exact(dataset):
    path, steps = write_synthetic_episode(dataset, seed=3, n_steps=N_STEPS)
    episode = read_episode(path)
    assert path.name.endswith(".mcap") and path.parent.name == "episodes"
    np.testing.assert_array_equal(episode.points, _stack(steps, lambda s: s["points_hand"]))
    assert episode.points.dtype == np.float32 and episode.points.shape == (N_STEPS, 256, 3)
    expected = {
        (S.TOPIC_TOOL_POSE, "position"): lambda s: s["tool_pose_hand"][0],
        (S.TOPIC_TOOL_POSE, "orientation"): lambda s: s["tool_pose_hand"][1],
        (S.TOPIC_JOINTS, "position"): lambda s: s["joint_position"],
        (S.TOPIC_JOINTS, "velocity"): lambda s: s["joint_velocity"],
        (S.TOPIC_LATENT, "z"): lambda s: s["latent_z"],
        (S.TOPIC_LATENT, "z_smoothed"): lambda s: s["latent_z_smoothed"],
        (S.TOPIC_ACTION, "values"): lambda s: s["action"],
        (S.TOPIC_GOAL, "z_goal"): lambda s: s["goal_z"],
        (S.TOPIC_REWARD, "goal"): lambda s: s["reward_terms"]["goal"],
        (S.TOPIC_OBJECT, "position"): lambda s: s["object_position_hand"],
        (S.TOPIC_TARGET, "position"): lambda s: s["target_position_hand"],
        (S.TOPIC_PRIVILEGED, "hinge_angle"): lambda s: s["privileged"]["hinge_angle"],
        (S.TOPIC_PRIVILEGED, "tip_a"): lambda s: s["privileged"]["tip_a"],
        (S.TOPIC_PRIVILEGED, "contact_count"): lambda s: s["privileged"]["contact_count"],
        (S.TOPIC_PRIVILEGED, "table_collision"): lambda s: s["privileged"]["table_collision"],
        (S.TOPIC_STEP, "observation"): lambda s: s["transition"]["observation"],
        (S.TOPIC_STEP, "action"): lambda s: s["transition"]["action"],
        (S.TOPIC_STEP, "reward"): lambda s: s["transition"]["reward"],
        (S.TOPIC_STEP, "truncated"): lambda s: s["transition"]["truncated"],
    }
    for (topic, field), getter in expected.items():
        want = _stack(steps, getter)
        got = episode[topic][field]
        np.testing.assert_array_equal(got, want, err_msg=f"{topic}:{field}")
        assert got.dtype == want.dtype, (topic, field, got.dtype, want.dtype)
    np.testing.assert_array_equal(episode[S.TOPIC_POINTS]["log_time_ns"],
                                  [round(k * CONTROL_DT_S * 1e9) for k in range(N_STEPS)])
    np.testing.assert_array_equal(episode.final["observation"], steps[-1]["transition"]["observation"])
    meta = episode.metadata
    assert (meta["source"], meta["seed"], meta["length"], meta["success"]) == ("synthetic", 3, N_STEPS, False)
    assert meta["return"] == pytest.approx(sum(s["transition"]["reward"] for s in steps), abs=0)
    assert meta["failure_reason"] == "timeout" and meta["joint_names"] == list(S.SVH_JOINT_NAMES)


def test_fast_and_generic_paths_agree(dataset):
    path, _ = write_synthetic_episode(dataset, seed=1, n_steps=N_STEPS, goal_env=True, chunk_bytes=20_000)
    fast, generic = read_episode(path), read_episode(path, generic=True)
    assert set(fast.topics) == set(generic.topics)
    for topic, fields in fast.topics.items():
        assert set(fields) == set(generic.topics[topic]), topic
        for name, array in fields.items():
            np.testing.assert_array_equal(array, generic.topics[topic][name])
            assert array.dtype == generic.topics[topic][name].dtype
    assert set(fast.final) == {"observation", "achieved_goal", "desired_goal"}


def test_plain_mcap_library_decodes_every_message(dataset):
    """The contract without hingelab: mcap + mcap_protobuf's decoder, schemas from the file."""
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    path, steps = write_synthetic_episode(dataset, seed=5, n_steps=N_STEPS)
    clouds, privileged, latents, metadata, schemas = [], [], [], {}, {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            schemas[channel.topic] = schema.name
            if channel.topic == "/tool/points":
                assert decoded.frame_id == "hand_base" and decoded.point_stride == 12
                assert [(fl.name, fl.offset) for fl in decoded.fields] == [("x", 0), ("y", 4), ("z", 8)]
                clouds.append((message.log_time, np.frombuffer(decoded.data, "<f4").reshape(-1, 3)))
            elif channel.topic == "/sim/privileged":
                privileged.append((message.log_time, decoded.hinge_angle))
            elif channel.topic == "/tool/latent":
                latents.append((list(decoded.z), list(decoded.z_smoothed)))
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    assert schemas["/tool/points"] == "foxglove.PointCloud"
    assert schemas["/tool/pose"] == "foxglove.PoseInFrame" and schemas["/tf"] == "foxglove.FrameTransform"
    assert schemas["/hand/joints"] == "foxglove.JointStates"
    assert len(clouds) == N_STEPS
    origin = int(metadata["episode"]["log_time_origin_ns"])  # schema 6: log time = wall-clock origin + episode time
    for k, (log_time, points) in enumerate(clouds):
        assert log_time == origin + round(k * CONTROL_DT_S * 1e9)
        np.testing.assert_array_equal(points, steps[k]["points_hand"])
    # the privileged state is logged at the same log time as the step's cloud
    assert [t for t, _ in privileged] == [t for t, _ in clouds]
    assert [h for _, h in privileged] == [s["privileged"]["hinge_angle"] for s in steps]
    assert latents[0] == (list(steps[0]["latent_z"]), list(steps[0]["latent_z_smoothed"]))
    episode = metadata["episode"]
    for key in ("source", "task", "object", "seed", "length", "return", "success", "attempt", "config_hash"):
        assert isinstance(episode[key], str), key
    assert episode["length"] == str(N_STEPS) and episode["success"] == "false" and episode["seed"] == "5"


def test_cloud_encoding_is_the_standard_serialization():
    points = np.random.default_rng(0).normal(size=(256, 3)).astype(np.float32)
    for log_time in (0, 7, 1_250_000_000, 3_000_000_001):
        reference = S.PointCloud(
            timestamp=codec.timestamp(log_time), frame_id="hand_base", point_stride=12,
            fields=[S.PackedElementField(name=n, offset=4 * i, type=S.PackedElementField.FLOAT32)
                    for i, n in enumerate("xyz")],
            data=points.tobytes())
        assert codec.encode_point_cloud(log_time, points) == reference.SerializeToString()


def test_time_offset_and_optional_topics(dataset):
    """A synthetic-cloud source: only clouds, pose and the true opening; log times start at the offset."""
    rng = np.random.default_rng(0)
    clouds = rng.normal(size=(5, 256, 3)).astype(np.float32)
    with EpisodeWriter(dataset, source="clouds", time_offset_s=100.0) as writer:
        for k in range(5):
            writer.write_step(k * 0.05, points_hand=clouds[k], tool_pose_hand=([0, 0, k], [0, 0, 0, 1]),
                              privileged={"hinge_angle": 0.1 * k})
    episode = read_episode(writer.path)
    assert set(episode.topics) == {S.TOPIC_POINTS, S.TOPIC_TOOL_POSE, S.TOPIC_PRIVILEGED}
    assert set(episode[S.TOPIC_PRIVILEGED]) == {"hinge_angle", "log_time_ns"}
    np.testing.assert_array_equal(episode.points, clouds)
    assert episode.time_s(S.TOPIC_POINTS)[0] == 100.0
    assert episode.metadata["length"] == 5 and episode.metadata["return"] == 0.0


def test_a_failing_episode_never_gets_a_final_name(dataset):
    with pytest.raises(RuntimeError):
        with EpisodeWriter(dataset, source="crash") as writer:
            writer.write_step(0.0, points_hand=np.zeros((256, 3), np.float32))
            raise RuntimeError("env exploded")
    assert list((dataset / "episodes").iterdir()) == []
    with pytest.raises(RuntimeError):
        with EpisodeWriter(dataset, source="crash", keep_partial_on_error=True) as writer:
            writer.write_step(0.0, points_hand=np.zeros((256, 3), np.float32))
            raise RuntimeError("env exploded")
    assert [p.name for p in (dataset / "episodes").iterdir()] == [writer.partial_path.name]


def test_writer_refuses_a_folder_without_card_and_backwards_time(tmp_path, dataset):
    with pytest.raises(DatasetError, match="dataset.json is missing"):
        EpisodeWriter(tmp_path, source="x")
    with pytest.raises(ValueError, match="back in time"):
        with EpisodeWriter(dataset, source="x") as writer:
            writer.write_step(1.0, privileged={"hinge_angle": 0.0})
            writer.write_step(0.5, privileged={"hinge_angle": 0.0})


def test_concurrent_writers_do_not_clobber(dataset):
    """Four processes write into one dataset at once: every episode lands, the index sees all."""
    import multiprocessing as mp

    from hingelab.episodes.dataset import Dataset

    ctx = mp.get_context("spawn")
    with ctx.Pool(2) as pool:
        pool.starmap(_write_some, [(str(dataset), seed) for seed in range(4)])
    index = Dataset(dataset).index
    assert len(index) == 8 and index["file"].is_unique
    assert sorted(index["seed"].tolist()) == [0, 0, 1, 1, 2, 2, 3, 3]


def _write_some(root: str, seed: int) -> None:
    for _ in range(2):
        write_synthetic_episode(root, seed=seed, n_steps=5)

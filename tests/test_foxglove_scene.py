"""What Foxglove needs (schema 6): log times at the episode's wall-clock start, /scene entities, the layout."""

from __future__ import annotations

import json
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from mcap.reader import make_reader
from scipy.spatial.transform import Rotation

from hingelab.episodes import EpisodeWriter, create_dataset, read_episode
from hingelab.episodes import schemas as S
from hingelab.episodes.reader import EpisodeFile
from hingelab.episodes.scene import TARGET_DIAMETER_M, TIP_DIAMETER_M
from hingelab.episodes.synthetic import CONTROL_DT_S, synthetic_step, write_synthetic_episode

LAYOUT = Path(__file__).resolve().parents[1] / "viewers" / "foxglove_layout.json"
N_STEPS = 12
TOPIC_KEYS = ("topic", "imageTopic", "calibrationTopic", "topicPath", "value")  # layout keys whose value is a topic


@pytest.fixture
def dataset(tmp_path):
    create_dataset(tmp_path / "ds", name="test", source="synthetic", config={"k": 1}, seed=0)
    return tmp_path / "ds"


def _raw_messages(path):
    with open(path, "rb") as f:
        return [(channel.topic, message) for _, channel, message in make_reader(f).iter_messages()]


def _write_old_style(dataset, seed: int):
    """The synthetic episode as a schema-5 writer wrote it: log times from 0, no log_time_origin_ns."""
    rng = np.random.default_rng(seed)
    steps = [synthetic_step(rng, k, N_STEPS) for k in range(N_STEPS)]
    writer = EpisodeWriter(dataset, source="synthetic", task="reach_latent", object="sphere", seed=seed,
                           action_level="low", log_time_origin_ns=0)
    writer.facts.pop(S.KEY_LOG_TIME_ORIGIN)
    writer.facts[S.KEY_SCHEMA_VERSION] = 5
    with writer:
        for k, step in enumerate(steps):
            writer.write_step(k * CONTROL_DT_S, **step)
        writer.write_final_observation(steps[-1]["transition"]["observation"])
    return writer.path


def test_log_times_start_at_the_wall_clock_start(dataset):
    before = time.time_ns()
    path, _ = write_synthetic_episode(dataset, seed=1, n_steps=N_STEPS)
    messages = _raw_messages(path)
    origin = read_episode(path).metadata[S.KEY_LOG_TIME_ORIGIN]
    assert abs(origin - before) < 1e9 and origin <= time.time_ns()
    assert min(m.log_time for _, m in messages) == origin
    assert all(m.publish_time == m.log_time for _, m in messages)
    clouds = [m.log_time for topic, m in messages if topic == S.TOPIC_POINTS]
    np.testing.assert_array_equal(np.array(clouds) - origin, np.round(np.arange(N_STEPS) * CONTROL_DT_S * 1e9))


@pytest.mark.parametrize("generic", [False, True])
def test_an_old_file_from_zero_reads_to_the_same_episode_times(dataset, generic):
    old = _write_old_style(dataset, seed=2)
    new, _ = write_synthetic_episode(dataset, seed=2, n_steps=N_STEPS)
    assert min(m.log_time for _, m in _raw_messages(old)) == 0
    assert min(m.log_time for _, m in _raw_messages(new)) > 1e18  # wall clock, ns since 1970
    a, b = read_episode(old, generic=generic), read_episode(new, generic=generic)
    assert a.metadata[S.KEY_SCHEMA_VERSION] == 5 and S.KEY_LOG_TIME_ORIGIN not in a.metadata
    assert set(a.topics) == set(b.topics) and S.TOPIC_SCENE not in b.topics
    for topic in a.topics:
        for name in a[topic]:
            np.testing.assert_array_equal(a[topic][name], b[topic][name], err_msg=f"{topic} {name}")
    np.testing.assert_allclose(b.time_s(), np.arange(N_STEPS) * CONTROL_DT_S)
    assert a.metadata[S.KEY_END_TIME] == b.metadata[S.KEY_END_TIME] == pytest.approx((N_STEPS - 1) * CONTROL_DT_S)
    with EpisodeFile(old) as f_old, EpisodeFile(new) as f_new:
        times_old = [t for _, t, _ in f_old.iter_messages([S.TOPIC_LATENT])]
        times_new = [t for _, t, _ in f_new.iter_messages([S.TOPIC_LATENT])]
        assert times_old == times_new and times_new[0] == 0


def _scenes(path) -> list[tuple[int, SceneUpdate]]:
    return [(m.log_time, SceneUpdate.FromString(m.data)) for topic, m in _raw_messages(path) if topic == S.TOPIC_SCENE]


def _entities(update: SceneUpdate) -> dict:
    return {e.id: e for e in update.entities}


def _xyz(v) -> list[float]:
    return [v.x, v.y, v.z]


def test_scene_entities_of_a_synthetic_episode(dataset):
    path, steps = write_synthetic_episode(dataset, seed=4, n_steps=N_STEPS, extra_metadata={"object_size": 0.025})
    scenes = _scenes(path)
    assert len(scenes) == N_STEPS
    origin = read_episode(path).metadata[S.KEY_LOG_TIME_ORIGIN]
    for k, (log_time, update) in enumerate(scenes):
        assert log_time == origin + round(k * CONTROL_DT_S * 1e9)
        entities = _entities(update)
        assert set(entities) == {S.SCENE_OBJECT, S.SCENE_TARGET, S.SCENE_TIP_A, S.SCENE_TIP_B}
        assert all(e.frame_id == S.FRAME_HAND for e in entities.values())
        sphere = entities[S.SCENE_OBJECT].spheres[0]
        np.testing.assert_allclose(_xyz(sphere.pose.position), steps[k]["object_position_hand"])
        np.testing.assert_allclose(_xyz(sphere.size), [0.025] * 3)
        target = entities[S.SCENE_TARGET].spheres[0]
        np.testing.assert_allclose(_xyz(target.pose.position), steps[k]["target_position_hand"])
        np.testing.assert_allclose(_xyz(target.size), [TARGET_DIAMETER_M] * 3)
        for entity_id, key in ((S.SCENE_TIP_A, "tip_a"), (S.SCENE_TIP_B, "tip_b")):
            tip = entities[entity_id].spheres[0]
            np.testing.assert_allclose(_xyz(tip.pose.position), steps[k]["privileged"][key])
            np.testing.assert_allclose(_xyz(tip.size), [TIP_DIAMETER_M] * 3)


def test_scene_of_a_short_tool_pick_episode(tmp_path):
    from hingelab.envs import TOOL_PICK_ID
    from hingelab.envs.recording import RecordingWrapper

    root = tmp_path / "pick"
    create_dataset(root, name="pick", source="high_level_evaluation", config={"object": "cube"}, seed=0)
    env = RecordingWrapper(gym.make(TOOL_PICK_ID, object="cube", size=0.02, max_episode_steps=3), root,
                           source="high_level_evaluation", object_name="cube", action_level="high",
                           extra_metadata={"object_size": 0.02})
    env.reset(seed=0)
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(np.zeros(env.action_space.shape, np.float32))
        done = terminated or truncated
    env.close()
    (path,) = env.paths
    episode = read_episode(path)
    scenes = _scenes(path)
    assert len(scenes) == episode.length + 1  # the reset record and each step
    ids = [sorted(e.id for e in update.entities) for _, update in scenes]
    assert all(i == sorted(S.SCENE_ENTITIES) for i in ids)  # every entity at every step, the same ids
    privileged, objects = episode[S.TOPIC_PRIVILEGED], episode[S.TOPIC_OBJECT]
    for k, (_, update) in enumerate(scenes):
        entities = _entities(update)
        cube = entities[S.SCENE_OBJECT].cubes[0]
        np.testing.assert_allclose(_xyz(cube.size), [0.02] * 3)
        np.testing.assert_allclose(_xyz(cube.pose.position), objects["position"][k])
        np.testing.assert_allclose(_xyz(entities[S.SCENE_TIP_A].spheres[0].pose.position), privileged["tip_a"][k])
        platform = entities[S.SCENE_PLATFORM].cubes[0]
        np.testing.assert_allclose(_xyz(platform.size), [0.2, 0.2, 0.2])  # the scene's 20 cm platform
    # the cube rests on the platform: its centre half its edge above the platform's top, in the platform's frame
    _, first = scenes[0]
    platform = _entities(first)[S.SCENE_PLATFORM].cubes[0]
    q = platform.pose.orientation
    rot = Rotation.from_quat([q.x, q.y, q.z, q.w])
    local = rot.inv().apply(np.asarray(objects["position"][0]) - _xyz(platform.pose.position))
    assert local[2] - platform.size.z / 2 == pytest.approx(0.01, abs=0.004)


def test_layout_parses_and_names_only_topics_of_episodes():
    layout = json.loads(LAYOUT.read_text())
    text = json.dumps(layout)
    topics = set(S.TOPIC_TYPES)
    named = {t for t in _topic_strings(layout)}
    assert named and named <= topics, sorted(named - topics)
    for needed in (S.TOPIC_POINTS, S.TOPIC_SCENE, S.TOPIC_TOOL_POSE, S.TOPIC_DEPTH, S.TOPIC_LATENT, S.TOPIC_GOAL):
        assert needed in named, needed
    assert "Image!" in text and "3D!" in text and "Plot!" in text


def _topic_strings(node) -> set[str]:
    """Every string in the layout that names a topic: values of keys ``topic``/``imageTopic``, the keys of
    ``topics`` and the topic part of a plot path (``/tool/latent.z[0]``)."""
    out: set[str] = set()
    if isinstance(node, dict):
        for key, value in node.items():
            if key == "topics" and isinstance(value, dict):
                out |= {k for k in value if k.startswith("/")}
            if key in TOPIC_KEYS and isinstance(value, str) and value.startswith("/"):
                out.add(value.split(".")[0])
            out |= _topic_strings(value)
    elif isinstance(node, list):
        for value in node:
            out |= _topic_strings(value)
    return out


def test_the_scene_encoder_reusing_its_message_gives_what_a_fresh_one_gives():
    from hingelab.episodes.scene import SceneEncoder, encode_scene_update

    rng = np.random.default_rng(0)
    encoder = SceneEncoder()
    for k in range(6):  # entities come and go (a tip missing, NaN target): the message is rebuilt
        things = dict(object_position=rng.normal(size=3), object_orientation=rng.normal(size=4),
                      object_shape=("cube", "tetrahedron")[k % 2], object_size=0.015 + 0.002 * k,
                      target_position=np.full(3, np.nan) if k == 3 else rng.normal(size=3),
                      tip_a=rng.normal(size=3), tip_b=None if k == 2 else rng.normal(size=3))
        assert encoder.encode(10**18 + k, **things) == encode_scene_update(10**18 + k, **things)
    assert encoder.encode(0) is None

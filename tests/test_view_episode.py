"""``hingelab view`` of one real episode: save an .rrd and read it back with Rerun's own reader.

The episode is real: SimCore + the privileged heuristic pick the 2 cm sphere (it succeeds
in ~76 steps), with tool clouds from the perception package's synthesizer, hand joints,
tips, object and target in hand_base, the arm action, reward terms and per-step
success/attempt infos, all written through ``EpisodeWriter``. The latent is a stand-in
(the hinge opening, scaled) until the encoder exists.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pyarrow as pa
import pytest
from rerun.chunk import RrdReader
from scipy.spatial.transform import Rotation

from hingelab.cli.main import main
from hingelab.episodes import EpisodeWriter, create_dataset, read_episode
from hingelab.viewers import entities as E
from hingelab.viewers import view

CONTROL_DT_S = 0.05


def write_heuristic_episode(root, seed: int = 0, max_steps: int = 120):
    """Run the heuristic on the sphere until success (or ``max_steps``) and record every step."""
    from hingelab.heuristic.controller import PrivilegedHeuristic
    from hingelab.perception.clouds import CloudSynthesizer
    from hingelab.sim import scripted
    from hingelab.sim.core import SimCore
    from hingelab.sim.finger_synergy import FingerSynergy
    from hingelab.sim.objects import ObjectSpec

    obj = ObjectSpec("sphere", 0.02, 0.010)
    sim = SimCore("tool_pick", obj=obj)
    state = sim.reset(seed=seed, object_xy=scripted.platform_center(sim.model))
    target_world = state.object_pos_world + np.array([0.0, 0.0, 0.05])
    heuristic = PrivilegedHeuristic(sim, FingerSynergy.load(), obj)
    heuristic.reset(state, target_world)
    synthesizer = CloudSynthesizer(seed=seed)
    synthesizer.new_episode()
    z_smoothed, success = None, False
    xyzw = lambda wxyz: np.asarray(wxyz)[[1, 2, 3, 0]]  # noqa: E731  MuJoCo w x y z -> contract x y z w
    with EpisodeWriter(root, source="heuristic", task="tool_pick", object="sphere", seed=seed,
                       action_level="high") as writer:
        for k in range(max_steps):
            command = heuristic.act(state)
            sim.set_hand_targets(command.hand_targets)
            state = sim.step(arm_velocity=command.arm_velocity, hinge_target=command.hinge_target).state
            hand_rot = Rotation.from_quat(xyzw(state.hand_quat_world))
            target_hand = hand_rot.inv().apply(target_world - state.hand_pos_world)
            z = np.array([(state.hinge_angle - 0.15) / 0.1, state.tip_gap * 50.0])  # stand-in latent
            z_smoothed = z if z_smoothed is None else 0.9 * z_smoothed + 0.1 * z
            distance = float(np.linalg.norm(state.object_pos_hand - target_hand))
            success = distance < 0.01
            q, qd = sim.hand_observation()
            terms = {"dense": float(np.exp(-20 * distance)), "sparse": 10.0 * success}
            writer.write_step(
                k * CONTROL_DT_S, points_hand=synthesizer.from_sim(sim.model, sim.data),
                tool_pose_hand=(state.tool_pos_hand, xyzw(state.tool_quat_hand)),
                joint_position=q, joint_velocity=qd, latent_z=z, latent_z_smoothed=z_smoothed,
                action=np.concatenate([z, command.arm_velocity]), goal_z=z, reward_terms=terms,
                object_position_hand=state.object_pos_hand, target_position_hand=target_hand,
                privileged={"hinge_angle": state.hinge_angle, "tool_position": state.tool_pos_hand,
                            "tool_orientation": xyzw(state.tool_quat_hand), "tip_a": state.tip_a_hand,
                            "tip_b": state.tip_b_hand, "object_position": state.object_pos_hand,
                            "contact_count": state.n_contacts, "table_collision": state.table_collision},
                transition={"observation": np.concatenate([z, state.object_pos_hand]), "action": command.arm_velocity,
                            "reward": sum(terms.values()), "terminated": success, "truncated": False,
                            "info": {"is_success": float(success), "attempt": float(heuristic.attempt)}},
            )
            if success:
                break
        writer.set_outcome(success=success, failure_reason=None if success else "timeout")
    return writer.path


def rrd_tables(path) -> dict[str, pa.Table]:
    """{entity path: all its rows} of an .rrd, read with Rerun's own chunk reader."""
    batches = defaultdict(list)
    for chunk in RrdReader(path).stream().to_chunks():
        batches[chunk.entity_path].append(chunk.to_record_batch())
    tables = {}
    for entity, parts in batches.items():
        tables[entity] = pa.concat_tables([pa.Table.from_batches([b]) for b in parts], promote_options="permissive")
    return tables


def sorted_by(table: pa.Table, timeline: str) -> pa.Table:
    """The rows logged on ``timeline`` (static rows, e.g. colors, dropped), in its order."""
    return table.filter(table.column(timeline).is_valid()).sort_by(timeline)


@pytest.fixture(scope="module")
def episode_path(tmp_path_factory):
    root = tmp_path_factory.mktemp("real") / "heuristic"
    create_dataset(root, name="heuristic", source="heuristic", config={"test": "view"}, seed=0)
    return write_heuristic_episode(root)


@pytest.fixture(scope="module")
def recording(episode_path, tmp_path_factory):
    rrd = tmp_path_factory.mktemp("rrd") / "episode.rrd"
    result, _ = view(episode_path, save=rrd, progress=False)
    assert result.saved_to == rrd and result.kind == "episode"
    return rrd, rrd_tables(rrd), read_episode(episode_path)


def test_the_real_episode_succeeds(recording):
    _, _, episode = recording
    assert episode.metadata["success"] is True and 40 < episode.length <= 120


def test_cloud_rows_hold_every_point_of_every_step(recording):
    _, tables, episode = recording
    clouds = sorted_by(tables["/" + E.TOOL_CLOUD], E.TIMELINE_STEP)
    assert clouds.num_rows == episode.length
    counts = [len(row) for row in clouds.column("Points3D:positions").to_pylist()]
    assert counts == [256] * episode.length
    logged = np.asarray(clouds.column("Points3D:positions").combine_chunks().flatten().flatten(), np.float32)
    np.testing.assert_array_equal(logged.reshape(episode.length, 256, 3), episode.points)
    steps = clouds.column(E.TIMELINE_STEP).to_numpy()
    np.testing.assert_array_equal(steps, np.arange(episode.length))
    sim_time = clouds.column(E.TIMELINE_SIM_TIME).cast(pa.int64()).to_numpy()  # duration -> ns
    np.testing.assert_array_equal(sim_time, episode["/tool/points"]["log_time_ns"])


def test_latent_series_has_one_row_per_step(recording):
    _, tables, episode = recording
    for entity, field in ((E.LATENT_Z, "z"), (E.LATENT_Z_SMOOTHED, "z_smoothed")):
        table = sorted_by(tables["/" + entity], E.TIMELINE_STEP)
        assert table.num_rows == episode.length
        values = np.array(table.column("Scalars:scalars").to_pylist())
        np.testing.assert_allclose(values, episode["/tool/latent"][field])
    plane = sorted_by(tables["/" + E.PLANE_Z], E.TIMELINE_STEP)
    assert plane.num_rows == episode.length
    trajectory = tables["/" + E.PLANE_TRAJECTORY].column("LineStrips2D:strips").to_pylist()[0][0]
    assert len(trajectory) == episode.length


def test_success_marker_and_attempts(recording):
    _, tables, episode = recording
    success = sorted_by(tables["/" + E.SUCCESS], E.TIMELINE_STEP)
    values = np.array(success.column("Scalars:scalars").to_pylist()).ravel()
    assert len(values) == episode.length and values[-1] == 1.0 and values[:-1].sum() == 0.0
    events = sorted_by(tables["/" + E.EVENTS], E.TIMELINE_STEP)
    texts = events.column("TextLog:text").to_pylist()
    assert texts[-1] == ["success"]
    assert events.column(E.TIMELINE_STEP).to_pylist()[-1] == episode.length - 1
    attempts = sorted_by(tables["/" + E.ATTEMPT], E.TIMELINE_STEP)
    attempt = np.array(attempts.column("Scalars:scalars").to_pylist()).ravel()
    assert attempt.min() == 1.0


def test_scene_tool_frame_tips_and_reward_terms(recording):
    rrd, tables, episode = recording
    tool = sorted_by(tables["/" + E.TOOL_FRAME], E.TIMELINE_STEP)
    translation = np.array(tool.column("Transform3D:translation").to_pylist()).reshape(-1, 3)
    np.testing.assert_allclose(translation, episode["/tool/pose"]["position"])
    tips = sorted_by(tables["/" + E.TIPS], E.TIMELINE_STEP)
    assert [len(r) for r in tips.column("Points3D:positions").to_pylist()] == [2] * episode.length
    for term in ("dense", "sparse", "total"):
        assert sorted_by(tables[f"/{E.REWARD}/{term}"], E.TIMELINE_STEP).num_rows == episode.length
    joints = sorted_by(tables["/" + E.HAND_JOINTS], E.TIMELINE_STEP)
    assert np.array(joints.column("Scalars:scalars").to_pylist()).shape == (episode.length, 9)
    assert RrdReader(rrd).blueprints(), "the .rrd carries its blueprint"


def test_cli_view_saves_a_recording(episode_path, tmp_path, capsys):
    rrd = tmp_path / "cli.rrd"
    assert main(["view", str(episode_path), "--save", str(rrd)]) == 0
    out = capsys.readouterr().out
    assert str(rrd) in out and "1 episode" in out
    assert sorted_by(rrd_tables(rrd)["/" + E.TOOL_CLOUD], E.TIMELINE_STEP).num_rows == read_episode(episode_path).length


def test_a_reward_term_missing_from_the_reset_message_is_drawn_at_its_own_steps(episode_path):
    # low-level episodes recorded before the reset carried the drift term have one row fewer of it
    from hingelab.episodes import schemas as S
    from hingelab.viewers.episode_series import episode_series

    episode = read_episode(episode_path)
    reward = episode.topics[S.TOPIC_REWARD]
    reward["drift"] = -np.arange(1.0, len(reward["log_time_ns"]))  # none at the reset
    series = {s.entity: s for s in episode_series(episode)}
    drift = series[f"{E.REWARD}/drift"]
    assert all(len(s.values) == len(s.time_ns) == len(s.step) for s in series.values())
    np.testing.assert_array_equal(drift.time_ns, reward["log_time_ns"][1:])
    np.testing.assert_array_equal(series[f"{E.REWARD}/total"].time_ns, reward["log_time_ns"])

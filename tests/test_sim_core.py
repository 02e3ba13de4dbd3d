"""The sim core's contract: controls, privileged state, randomization, and bad input."""

from __future__ import annotations

import numpy as np
import pytest

from hingelab.errors import AssetError, ConfigError
from hingelab.sim import names
from hingelab.sim.core import SimCore
from hingelab.sim.delay import DelayLine
from hingelab.sim.objects import ObjectSpec
from hingelab.sim.randomization import RandomizationConfig
from hingelab.sim.scene import load_scene


def test_control_rate_is_20hz():
    sim = SimCore("tool_shape")
    sim.reset()
    assert sim.n_substeps * sim.model.opt.timestep == pytest.approx(0.05)
    state = sim.step().state
    assert state.time == pytest.approx(0.05)


def test_hand_action_is_a_relative_joint_target():
    sim = SimCore("tool_shape")
    sim.reset()
    q = sim.hand.q(sim.data)
    action = np.full(9, 0.02)
    sim.step(hand_action=action)
    expected = np.clip(q + action, sim.hand.ctrl_low, sim.hand.ctrl_high)
    np.testing.assert_allclose(sim.data.ctrl[sim.hand.actuator_ids], expected)


def test_arm_velocity_moves_the_hand_at_that_velocity_and_keeps_its_orientation():
    sim = SimCore("tool_pick")
    start = sim.reset()
    velocity = np.array([0.02, -0.01, 0.03])
    for _ in range(20):  # 1 s
        state = sim.step(arm_velocity=velocity).state
    moved = state.hand_pos_world - start.hand_pos_world
    np.testing.assert_allclose(moved, velocity * 1.0, atol=0.004)
    dot = abs(np.dot(state.hand_quat_world, start.hand_quat_world))
    assert np.degrees(2 * np.arccos(min(dot, 1.0))) < 1.0


def test_privileged_state_matches_the_simulator():
    sim = SimCore("tool_pick")
    state = sim.reset()
    d = sim.data
    assert state.hinge_angle == pytest.approx(float(d.joint(names.TOOL_HINGE).qpos[0]))
    rot_h = d.body(names.HAND_BASE_BODY).xmat.reshape(3, 3)
    tip_a = rot_h.T @ (d.site("tool_tip_a").xpos - d.body(names.HAND_BASE_BODY).xpos)
    np.testing.assert_allclose(state.tip_a_hand, tip_a)
    # tip gap follows the hinge: ~0.124 m * sin(angle)
    assert state.tip_gap == pytest.approx(0.124 * np.sin(state.hinge_angle), abs=0.002)
    np.testing.assert_allclose(state.object_pos_world, d.body("object").xpos)
    assert state.hand_tool_contacts > 0 and not state.table_collision
    assert set(state.as_dict()) >= {"hinge_angle", "tool_pos_hand", "table_collision"}


def test_table_collision_is_reported():
    sim = SimCore("tool_pick")
    sim.reset(object_xy=[0.56, 0.06])  # object out of the way
    collided = False
    for _ in range(60):
        result = sim.step(arm_velocity=[0.0, 0.0, -0.1])
        collided |= result.state.table_collision
    assert collided


def test_same_seed_same_trajectory():
    def run(seed):
        sim = SimCore("tool_shape", randomization=RandomizationConfig(), seed=seed)
        sim.reset()
        rng = np.random.default_rng(1)
        return np.array([sim.step(hand_action=rng.uniform(-0.02, 0.02, 9)).state.hinge_angle for _ in range(15)])

    np.testing.assert_array_equal(run(3), run(3))
    assert not np.array_equal(run(3), run(4))


def test_domain_randomization_ranges_and_restore():
    sim = SimCore("tool_pick", obj=ObjectSpec("cube", 0.02, 0.01), randomization=RandomizationConfig(), seed=0)
    nominal_kp = sim.model.actuator_gainprm[sim.hand.actuator_ids, 0].copy()
    for seed in range(5):
        sim.reset(seed=seed)
        ep = sim.episode
        assert np.all((ep.gain_scale >= 0.6) & (ep.gain_scale <= 1.5))
        kp = sim.model.actuator_gainprm[sim.hand.actuator_ids, 0]
        np.testing.assert_allclose(kp, nominal_kp * ep.gain_scale[:9])
        assert np.all((ep.geom_friction >= 0.2) & (ep.geom_friction <= 1.0))
        assert 1.0 <= ep.object_friction <= 5.0
        assert sim.model.geom_friction[sim.model.geom("object_geom").id, 0] == ep.object_friction
        assert 0.0 <= ep.observation_delay_s <= 0.150
    sim.randomizer.restore()
    np.testing.assert_allclose(sim.model.actuator_gainprm[sim.hand.actuator_ids, 0], nominal_kp)


def test_delay_line_reads_the_past():
    line = DelayLine(period=0.05, max_delay=0.15)
    line.reset(np.array([0.0]))
    for k in range(1, 6):
        line.push(np.array([float(k)]))
    assert line.read(0.0)[0] == 5.0
    assert line.read(0.10)[0] == pytest.approx(3.0)
    assert line.read(0.125)[0] == pytest.approx(2.5)


def test_observation_delay_is_applied_to_the_hand_state():
    sim = SimCore("tool_shape", randomization=RandomizationConfig(), seed=0)
    sim.reset()
    sim.episode = type(sim.episode)(sim.episode.gain_scale, sim.episode.geom_friction, 1.0, 0.10)
    history = []
    for _ in range(6):
        sim.step(hand_action=np.full(9, 0.03))
        history.append(sim.hand.q(sim.data))
    delayed_q, _ = sim.hand_observation()
    np.testing.assert_allclose(delayed_q, history[-3], atol=1e-9)


@pytest.mark.parametrize("bad", [np.full(9, np.nan), [0.0] * 8])
def test_bad_hand_action_is_a_clear_error(bad):
    sim = SimCore("tool_shape")
    sim.reset()
    with pytest.raises(ConfigError, match="hand action"):
        sim.step(hand_action=bad)


def test_arm_velocity_needs_the_arm_and_a_sane_speed():
    with pytest.raises(ConfigError, match="no arm"):
        shape = SimCore("tool_shape")
        shape.reset()
        shape.step(arm_velocity=[0.0, 0.0, 0.01])
    pick = SimCore("tool_pick")
    pick.reset()
    with pytest.raises(ConfigError, match="exceeds"):
        pick.step(arm_velocity=[5.0, 0.0, 0.0])


def test_diverging_simulation_ends_the_episode_with_a_flag():
    sim = SimCore("tool_shape")
    sim.reset()
    sim.data.qvel[:] = 1e12  # an exploding state
    result = sim.step()
    assert result.diverged and result.reason
    with pytest.raises(ConfigError, match="reset"):
        sim.step()
    sim.reset()
    assert not sim.step().diverged


@pytest.mark.parametrize("shape", ["sphere", "cube", "cylinder", "tetrahedron"])
@pytest.mark.parametrize("size", [0.015, 0.025])
def test_object_is_swapped_with_its_size_and_mass(shape, size):
    sim = SimCore("tool_pick", obj=ObjectSpec(shape, size, 0.015))
    sim.reset()
    body = sim.model.body("object")
    assert body.mass[0] == pytest.approx(0.015)
    geom = sim.model.geom("object_geom")
    # the geom's extent along x equals the object's width (tetrahedron: its edge)
    aabb = sim.model.geom_aabb[geom.id]
    width = 2 * aabb[3] if shape != "tetrahedron" else None
    if width is not None:
        assert width == pytest.approx(size, rel=1e-6)
    for _ in range(10):  # it rests on the platform, it does not fall or jump
        state = sim.step().state
    assert abs(state.object_pos_world[2] - sim.data.body("object").xpos[2]) < 1e-9
    top = sim.model.geom_pos[sim.model.geom("platform").id][2] + sim.model.geom_size[sim.model.geom("platform").id][2]
    assert state.object_pos_world[2] - top == pytest.approx(ObjectSpec(shape, size, 0.015).rest_height, abs=0.002)


def test_unknown_object_and_bad_sizes_are_one_line_errors():
    with pytest.raises(ConfigError, match="unknown object 'banana'.*sphere"):
        ObjectSpec("banana")
    with pytest.raises(ConfigError, match="out of range"):
        ObjectSpec("cube", 0.5)
    with pytest.raises(ConfigError, match="out of range"):
        ObjectSpec("cube", float("nan"))
    with pytest.raises(ConfigError, match="mass"):
        ObjectSpec("cube", 0.02, -1.0)


def test_missing_and_malformed_assets_name_the_file_and_the_fix(tmp_path):
    missing = tmp_path / "nope.xml"
    with pytest.raises(AssetError, match=r"nope\.xml is missing.*scene_builder"):
        load_scene(str(missing))
    broken = tmp_path / "broken.xml"
    broken.write_text("<mujoco><worldbody><body name='x'>")
    with pytest.raises(AssetError, match=r"broken\.xml is malformed"):
        load_scene(str(broken))
    with pytest.raises(ConfigError, match="unknown scene"):
        load_scene("tool_juggle")


def test_scene_without_interface_is_rejected(tmp_path):
    bare = tmp_path / "bare.xml"
    bare.write_text("<mujoco><worldbody><body name='b'><freejoint/><geom size='0.1'/></body></worldbody></mujoco>")
    with pytest.raises(AssetError, match="lacks body 'hand_base'"):
        load_scene(str(bare))


def test_contact_counts_match_a_count_by_hand():
    """The compiled contact bookkeeping against the categories of every active contact."""
    from hingelab.sim import privileged as pv

    sim = SimCore("tool_shape", randomization=RandomizationConfig(enabled=False))
    sim.reset(seed=0)
    for _ in range(3):
        sim.step(hand_action=np.zeros(9))
    reader, d = sim.reader, sim.data
    pairs = [sorted(reader.geom_category[g] for g in d.contact.geom[i]) for i in range(d.ncon)]
    hand_tool = sum(p == [pv.HAND, pv.TOOL] for p in pairs)
    assert hand_tool > 0
    expected = (d.ncon, hand_tool, sum(p == [pv.TOOL, pv.OBJECT] for p in pairs),
                any(p[1] == pv.TABLE and p[0] in (pv.ARM, pv.HAND, pv.TOOL) for p in pairs))
    assert reader.contact_counts(d) == expected

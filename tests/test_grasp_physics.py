"""The robot platform's physical checks (issue 2): the tool held by contact, worked by the
fingers, carried by the arm, and the privileged grasp lifting the sphere."""

from __future__ import annotations

import numpy as np
import pytest

from hingelab.sim import scripted
from hingelab.sim.core import SimCore
from hingelab.sim.objects import ObjectSpec


@pytest.mark.parametrize("scene", ["tool_shape", "tool_pick"])
def test_grasp_keyframe_holds_the_tool_for_ten_seconds(scene):
    sim = SimCore(scene)
    sim.reset()
    drift = scripted.hold(sim, 10.0)
    assert drift.max_mm < 5.0
    assert drift.max_deg < 5.0


def test_fingers_alone_open_and_close_the_hinge_over_half_its_range(synergy):
    sim = SimCore("tool_shape")
    sim.reset()
    hinge_range = sim.model.jnt_range[sim.model.joint("tool_hinge").id]
    result = scripted.work_tool_with_fingers(sim, synergy)
    # the privileged hinge servo stayed off: only the 9 hand actuators moved the tool
    assert sim.model.actuator_gainprm[sim.model.actuator("tool_hinge_cmd").id, 0] == 0.0
    assert result.hinge_range >= 0.5 * (hinge_range[1] - hinge_range[0])
    assert result.drift.max_mm < 20.0
    assert result.drift.max_deg < 20.0
    # it really went both ways: open near the top of the synergy and closed near the bottom
    assert result.hinge_max > 0.2 and result.hinge_min < 0.05


def test_arm_carries_the_tips_over_a_10cm_square_on_the_platform():
    sim = SimCore("tool_pick")
    sim.reset()
    top = scripted.platform_top(sim.model)
    center = scripted.platform_center(sim.model)
    drift = scripted.drift_from(sim)
    for dx in (-0.05, 0.0, 0.05):
        for dy in (-0.05, 0.0, 0.05):
            target = np.array([center[0] + dx, center[1] + dy, top + 0.01])
            result = scripted.move_grip_to(sim, target, drift=drift)
            assert result.error_m < 0.002, f"tips missed {target} by {result.error_m * 1000:.1f} mm"
            assert not result.table_collision
    assert drift.max_mm < 5.0


def test_privileged_hinge_command_grasps_and_lifts_the_sphere_by_friction(synergy):
    sim = SimCore("tool_pick")
    state = sim.reset()
    assert state.tool_object_contacts == 0
    result = scripted.grasp_and_lift(sim, synergy, object_size=0.02, lift=0.05)
    assert result.lifted_m > 0.045
    assert result.tool_object_contacts > 0
    assert result.object_between_tips
    assert not result.table_collision_on_approach


@pytest.mark.parametrize("shape", ["cube", "cylinder"])
def test_test_objects_can_be_grasped_too(synergy, shape):
    sim = SimCore("tool_pick", obj=ObjectSpec(shape, 0.02, 0.01))
    sim.reset()
    result = scripted.grasp_and_lift(sim, synergy, object_size=0.02, lift=0.03)
    assert result.lifted_m > 0.025

"""The committed scenes are what the builder makes from the part models."""

from __future__ import annotations

import json

import mujoco
import numpy as np

from hingelab.paths import SCENES_DIR
from hingelab.sim import scene_builder


def test_rebuilt_scenes_match_the_committed_ones(tmp_path):
    summary = scene_builder.build(tmp_path)
    for name in ("tool_shape", "tool_pick"):
        fresh = mujoco.MjModel.from_xml_path(str(tmp_path / f"{name}.xml"))
        committed = mujoco.MjModel.from_xml_path(str(SCENES_DIR / f"{name}.xml"))
        assert fresh.nq == committed.nq and fresh.nbody == committed.nbody
        # the grasp keyframe is settled by physics: same parts, same state (to float noise)
        np.testing.assert_allclose(fresh.key("grasp").qpos, committed.key("grasp").qpos, atol=1e-5,
                                   err_msg=f"{name}.xml is stale: run `python -m hingelab.sim.scene_builder`")
    fresh_synergy = json.loads((tmp_path / "grasp_synergy.json").read_text())
    committed_synergy = json.loads((SCENES_DIR / "grasp_synergy.json").read_text())
    np.testing.assert_allclose(fresh_synergy["targets"], committed_synergy["targets"], atol=1e-4)
    assert summary["synergy_hinge_range"][1] > 0.2

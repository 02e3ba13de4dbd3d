"""Goal-region experts: the goal's opening picks the checkpoint that acts (hingelab compose low)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from hingelab.cli.main import main
from hingelab.errors import ConfigError


class _Constant:
    """A stand-in expert: every action is its own number, so the routing shows in the output."""

    def __init__(self, value, like):
        self.value, self.observation_space, self.action_space = value, like.observation_space, like.action_space

    def predict(self, obs, deterministic=True):
        goals = np.asarray(obs["desired_goal"])
        shape = (9,) if goals.ndim == 1 else (len(goals), 9)
        return np.full(shape, self.value, np.float32), None


@pytest.fixture(scope="module")
def shipped():
    from hingelab.envs.low_level import PolicyLowLevel
    from hingelab.perception.encoder import shipped_encoder
    from hingelab.policies.low_level import SHIPPED_LOW_LEVEL_SAC

    return SHIPPED_LOW_LEVEL_SAC, PolicyLowLevel(SHIPPED_LOW_LEVEL_SAC).model, shipped_encoder().calibration


def _observation(calibration, openings):
    goals = np.stack([calibration.z_for_opening(o) for o in openings])
    n = len(goals)
    return {"observation": np.zeros((n, 26)), "achieved_goal": np.zeros((n, 2)), "desired_goal": goals}


def test_each_goal_goes_to_the_expert_of_its_band(shipped):
    from hingelab.policies.goal_experts import GoalRegionExperts

    _, model, calibration = shipped
    experts = GoalRegionExperts([_Constant(v, model) for v in (1, 2, 3)], [0.05, 0.15], calibration, {})
    openings = [0.0, 0.04, 0.06, 0.14, 0.16, 0.25]
    batch = _observation(calibration, openings)
    actions, _ = experts.predict(batch)
    np.testing.assert_array_equal(actions[:, 0], [1, 1, 2, 2, 3, 3])
    single = {key: value[2] for key, value in batch.items()}  # unbatched, as gymnasium gives it
    action, _ = experts.predict(single)
    assert action.shape == (9,) and action[0] == 2
    with pytest.raises(ConfigError, match="must increase"):
        GoalRegionExperts([_Constant(v, model) for v in (1, 2, 3)], [0.15, 0.05], calibration, {})


def test_compose_writes_a_manifest_that_eval_and_the_envs_take(tmp_path, shipped, capsys):
    """Two copies of the shipped policy split at 0.10 rad act as the shipped policy does: same
    actions on a batch of goals on both sides of the split."""
    from hingelab.envs.low_level import PolicyLowLevel

    path, model, calibration = shipped
    for name in ("closed.zip", "rest.zip"):
        shutil.copy(path, tmp_path / name)
    out = tmp_path / "policies" / "experts.json"
    assert main(["compose", "low", "--expert", f"{tmp_path / 'closed.zip'}:0.10", "--expert",
                 str(tmp_path / "rest.zip"), "--out", str(out)]) == 0
    assert "2 experts" in capsys.readouterr().out
    manifest = json.loads(out.read_text())
    assert [e["checkpoint"] for e in manifest["experts"]] == ["../closed.zip", "../rest.zip"]
    assert manifest["experts"][0]["up_to_rad"] == 0.10 and manifest["git_commit"]
    policy = PolicyLowLevel(out).model
    assert policy.hingelab_provenance["policy"] == "goal-region experts"
    assert policy.hingelab_provenance["encoder_fingerprint"] == model.hingelab_provenance["encoder_fingerprint"]
    batch = _observation(calibration, [0.02, 0.08, 0.12, 0.2])
    batch["observation"] = np.random.default_rng(0).normal(0, 0.3, (4, 26))
    np.testing.assert_allclose(policy.predict(batch)[0], model.predict(batch, deterministic=True)[0], atol=1e-6)
    assert (policy.expert_index(batch["desired_goal"]) == [0, 0, 1, 1]).all()


def test_bad_manifests_and_changed_experts_are_refused(tmp_path, shipped, capsys):
    from hingelab.policies.goal_experts import load_experts, write_experts

    path, _, _ = shipped
    a, b = tmp_path / "a.zip", tmp_path / "b.zip"
    shutil.copy(path, a)
    shutil.copy(path, b)
    with pytest.raises(ConfigError, match="does not exist"):
        write_experts(tmp_path / "x.json", [(tmp_path / "missing.zip", 0.1), (b, None)])
    with pytest.raises(ConfigError, match="a .json file"):
        write_experts(tmp_path / "x.zip", [(a, 0.1), (b, None)])
    with pytest.raises(ConfigError, match="must increase"):
        write_experts(tmp_path / "x.json", [(a, 0.2), (b, 0.1), (b, None)])
    assert not (tmp_path / "x.json").exists() and not (tmp_path / "x.json.tmp").exists()
    out = write_experts(tmp_path / "ok.json", [(a, 0.1), (b, None)])
    with open(b, "ab") as f:  # the expert changed after composing
        f.write(b"\0")
    with pytest.raises(ConfigError, match="changed since the manifest"):
        load_experts(out)
    (tmp_path / "other.json").write_text(json.dumps({"format": "something else"}))
    with pytest.raises(ConfigError, match="not a hingelab-low-level-experts manifest"):
        load_experts(tmp_path / "other.json")
    assert main(["compose", "low", "--expert", str(a), "--expert", str(b), "--out", str(tmp_path / "y.json")]) == 1
    assert "an opening bound" in capsys.readouterr().err

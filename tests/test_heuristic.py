"""The privileged heuristic and `hingelab generate heuristic`: real episodes, recorded."""

from __future__ import annotations

import numpy as np
import pytest

from hingelab.episodes import read_episode
from hingelab.episodes.dataset import Dataset
from hingelab.episodes.verify import verify_dataset
from hingelab.rollouts.heuristic_demos import HeuristicRunConfig, generate_heuristic_dataset


@pytest.fixture(scope="module")
def sphere_dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("heur") / "sphere"
    summaries = generate_heuristic_dataset(out, HeuristicRunConfig(episodes=3, seed=5), progress=False)
    return out, summaries


def test_heuristic_picks_the_sphere_and_records_every_step(sphere_dataset):
    out, summaries = sphere_dataset
    assert all(s.success for s in summaries)
    index = Dataset(out).index
    assert len(index) == 3 and index["success"].all() and (index["source"] == "heuristic").all()
    # one verdict (ToolPick-v0's: the object within 1 cm of the target), named, and no secondary one
    assert (index["success_verdict"] == "object_within_1cm").all() and index["last_step_success"].isna().all()
    by_seed = index.set_index("seed")["success"]
    assert all(by_seed[s.seed] == s.success for s in summaries)
    episode = read_episode(out / "episodes" / index["file"].iloc[0])
    steps = episode["/step"]
    length = len(steps["action"])
    assert episode.points.shape == (length + 1, 256, 3)  # the reset's cloud and one per step
    assert steps["observation"].shape == (length, 14)
    assert episode.length == length  # the steps; the reset's record is not one (schema 2)
    assert int(index["length"].sum()) == sum(s.length for s in summaries)  # datasets info = the rollouts' count
    # the recorded action: the reached latent as z_goal (paper), in the normalized action space
    z_bar = episode["/tool/latent"]["z_smoothed"][1:]
    np.testing.assert_allclose(steps["action"][:, :2], np.clip(z_bar / 3.0, -1, 1), atol=1e-9)
    assert np.abs(steps["action"]).max() <= 1.0
    hinge = episode["/sim/privileged"]["hinge_angle"]
    assert hinge.max() - hinge.min() > 0.05  # it opened and closed the tweezer
    assert steps["terminated"][-1] and not steps["terminated"][:-1].any()
    assert episode.metadata["object_size"] in ("0.02", 0.02)
    good, problems = verify_dataset(out)  # /step indices 1..length after the reset record: sound
    assert len(good) == 3 and problems == []


def test_same_seed_same_dataset_whatever_the_workers(sphere_dataset, tmp_path):
    out, _ = sphere_dataset
    other = tmp_path / "two_workers"
    generate_heuristic_dataset(other, HeuristicRunConfig(episodes=3, seed=5, workers=2), progress=False)

    def by_seed(root):
        index = Dataset(root).index.sort_values("seed")
        return [read_episode(root / "episodes" / f) for f in index["file"]]

    for a, b in zip(by_seed(out), by_seed(other)):
        assert a.metadata["seed"] == b.metadata["seed"]
        np.testing.assert_array_equal(a["/step"]["action"], b["/step"]["action"])
        np.testing.assert_array_equal(a.points, b.points)


def test_cli_generates_and_summarizes(tmp_path, capsys):
    from hingelab.cli.main import main

    out = tmp_path / "cube"
    capsys.readouterr()
    assert main(["generate", "heuristic", "--episodes", "2", "--object", "cube", "--size", "0.015", "--out",
                 str(out), "--no-progress"]) == 0
    stdout = capsys.readouterr().out
    assert "success" in stdout and "2 episodes" in stdout
    assert len(Dataset(out).index) == 2


def test_cli_bad_object_is_one_line(tmp_path, capsys):
    from hingelab.cli.main import main

    capsys.readouterr()
    assert main(["generate", "heuristic", "--object", "banana", "--out", str(tmp_path / "x")]) == 1
    stderr = capsys.readouterr().err
    assert stderr.strip().count("\n") == 0 and "unknown object 'banana'" in stderr
    assert not (tmp_path / "x").exists()


def test_the_squeeze_cap_and_close_tracking_as_the_scripted_high_level_sets_them():
    """``max_squeeze_fraction`` keeps a small object's squeeze from shutting the tips (the 1.5 cm
    tetrahedron: 0.05 rad past a 0.04 rad contact); ``close_tracking`` servos the grip point onto the
    object while closing, where the heuristic's own close stands still."""
    import gymnasium as gym

    from hingelab.envs import TOOL_PICK_ID
    from hingelab.heuristic.controller import HeuristicConfig, PrivilegedHeuristic
    from hingelab.policies.baselines import ScriptedPolicy
    from hingelab.sim.finger_synergy import FingerSynergy
    from hingelab.sim.scripted import grip_point

    env = gym.make(TOOL_PICK_ID, object="tetrahedron", size=0.015, low_level="privileged")
    env.reset(seed=3)
    pick = env.unwrapped

    def heuristic(**fields):
        h = PrivilegedHeuristic(pick.sim, FingerSynergy.load(), pick.object, HeuristicConfig(**fields))
        h.reset(pick.state, pick.target)
        h.phase, h.hinge_cmd = "close", h.contact_theta  # closing, the tips at the object's width
        return h

    own = heuristic()
    assert own.contact_theta < own.config.squeeze  # the full squeeze would aim past shut
    scripted = heuristic(**ScriptedPolicy.heuristic_config)
    assert scripted.squeeze == pytest.approx(0.5 * scripted.contact_theta)
    for _ in range(10):
        floor_own, floor_scripted = own.act(pick.state).hinge_target, scripted.act(pick.state).hinge_target
    assert floor_own == pytest.approx(own.contact_theta - own.config.squeeze) and floor_own < 0
    assert floor_scripted == pytest.approx(0.5 * scripted.contact_theta) and floor_scripted > 0
    # the grip point away from the object: the scripted close moves toward it, the heuristic's does not
    own, scripted = heuristic(), heuristic(**ScriptedPolicy.heuristic_config)
    offset = scripted._grip_target(pick.state) - grip_point(pick.sim)
    assert np.linalg.norm(offset) > 0.01  # the reset's hand is centimetres off
    velocity = scripted.act(pick.state).arm_velocity
    assert np.dot(velocity, offset) > 0 and np.linalg.norm(velocity) > 0
    assert not own.act(pick.state).arm_velocity.any()
    env.close()

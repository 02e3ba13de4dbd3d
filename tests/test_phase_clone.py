"""The phase clone (``train high --learner phase-clone``): a policy whose memory is the phase it predicts.

On synthetic demos it learns a phase switch the observation alone cannot tell (a count of steps) and
keeps its own memory; its zip round-trips without unpickling; a tiny run through the command line
generates scripted demos that record the demonstrator's phases, clones them, evaluates, and
``eval high`` drives the result; bad input gets one-line errors."""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pandas as pd
import pytest

from hingelab.errors import ConfigError
from hingelab.learners.phase_clone.fit import PhaseDemos, fit_phase_clone
from hingelab.policies.phase_clone import PHASES, PhaseClone, is_phase_clone


def _timer_demos(episodes: int = 40, seed: int = 0) -> PhaseDemos:
    """The same observation throughout; phase "open" for 5 steps, then "above": action +0.5 then -0.5.
    Only a policy that counts its steps in the phase can act right."""
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(episodes):
        obs = rng.normal(0, 1, 4).astype(np.float32)
        phase, steps = 0, 0
        for _ in range(10):
            next_phase = 1 if (phase == 1 or steps >= 4) else 0
            action = np.full(5, 0.5 if phase == 0 else -0.5, np.float32)
            rows.append((obs, action, phase, steps, next_phase))
            steps = steps + 1 if next_phase == phase else 0
            phase = next_phase
    obs, actions, phases, steps, nxt = zip(*rows)
    return PhaseDemos(np.array(obs), np.array(actions), np.array(phases), np.array(steps), np.array(nxt))


@pytest.fixture(scope="module")
def timer_clone():
    net, fit = fit_phase_clone(_timer_demos(), (32, 32), 1000, 64, 1e-2, seed=0)
    return PhaseClone(net, {"env_kwargs": {}}), fit


def test_the_clone_keeps_its_own_phase_memory(timer_clone):
    clone, fit = timer_clone
    assert fit["phase_accuracy"] > 0.99 and fit["phase_change_accuracy"] > 0.9
    obs = np.random.default_rng(5).normal(0, 1, 4)
    state, actions, phases = None, [], []
    for _ in range(10):
        action, state = clone.predict(obs, state=state)
        actions.append(float(action[0]))
        phases.append(PHASES[int(state[0, 0])])
    # the same observation ten times: the switch comes from the memory alone, after 5 steps in "open"
    assert phases == ["open"] * 4 + ["above"] * 6
    assert all(a > 0.3 for a in actions[:5]) and all(a < -0.3 for a in actions[5:])
    # a new episode starts in "open" again
    action, state = clone.predict(obs, state=state, episode_start=np.array([True]))
    assert action[0] > 0.3 and int(state[0, 0]) == 0


def test_a_batch_steps_each_memory_apart(timer_clone):
    clone, _ = timer_clone
    obs = np.zeros((2, 4))
    state = np.array([[0, 0], [1, 3]])
    actions, state = clone.predict(obs, state=state)
    assert actions.shape == (2, 5) and actions[0, 0] > 0.3 and actions[1, 0] < -0.3
    assert state.tolist() == [[0, 1], [1, 4]]


def test_the_zip_round_trips_without_pickles(timer_clone, tmp_path):
    clone, _ = timer_clone
    clone.save(tmp_path / "clone.zip")
    assert is_phase_clone(tmp_path / "clone.zip")
    with zipfile.ZipFile(tmp_path / "clone.zip") as archive:
        assert sorted(archive.namelist()) == ["phase_clone.json", "weights.npz"]
        np.load(io.BytesIO(archive.read("weights.npz")), allow_pickle=False)  # plain arrays
    loaded = PhaseClone.load(tmp_path / "clone.zip")
    obs = np.random.default_rng(1).normal(0, 1, (3, 4))
    state = np.array([[0, 2], [1, 0], [0, 4]])
    a1, s1 = clone.predict(obs, state=state)
    a2, s2 = loaded.predict(obs, state=state)
    np.testing.assert_array_equal(a1, a2)
    np.testing.assert_array_equal(s1, s2)
    (tmp_path / "bad.zip").write_bytes(b"not a zip")
    assert not is_phase_clone(tmp_path / "bad.zip")
    with zipfile.ZipFile(tmp_path / "other.zip", "w") as archive:
        archive.writestr("phase_clone.json", json.dumps({"format": "something else"}))
        archive.writestr("weights.npz", b"")
    with pytest.raises(ConfigError, match="another layout"):
        PhaseClone.load(tmp_path / "other.zip")



def test_an_ensemble_acts_on_its_members_mean_and_round_trips(tmp_path):
    from hingelab.learners.phase_clone.fit import fit_phase_clone_members

    nets, fit = fit_phase_clone_members(_timer_demos(), 2, (32, 32), 300, 64, 1e-2, seed=0)
    assert len(nets) == 2 and fit["members"] == 2 and len(fit["member_fits"]) == 2
    ensemble = PhaseClone(nets)
    obs = np.random.default_rng(2).normal(0, 1, (3, 4))
    state = np.array([[0, 2], [1, 0], [0, 4]])
    singles = [PhaseClone(net).predict(obs, state=state)[0] for net in nets]
    assert not np.allclose(singles[0], singles[1])  # different seeds: different members
    action, next_state = ensemble.predict(obs, state=state)
    np.testing.assert_allclose(action, (singles[0] + singles[1]) / 2, atol=1e-6)
    ensemble.save(tmp_path / "ensemble.zip")
    loaded = PhaseClone.load(tmp_path / "ensemble.zip")
    assert len(loaded.nets) == 2
    a2, s2 = loaded.predict(obs, state=state)
    np.testing.assert_array_equal(action, a2)
    np.testing.assert_array_equal(next_state, s2)
    # member 0 is the one-net fit of the same seed
    one, _ = fit_phase_clone(_timer_demos(), (32, 32), 300, 64, 1e-2, seed=0)
    np.testing.assert_array_equal(PhaseClone(one).predict(obs, state=state)[0], singles[0])


def test_a_one_net_zip_of_the_first_format_still_loads(timer_clone, tmp_path):
    """``hingelab phase clone 1`` (before ensembles): one net's weights unprefixed, ``hidden`` flat."""
    clone, _ = timer_clone
    net = clone.nets[0]
    weights = io.BytesIO()
    np.savez(weights, **{k: v.numpy() for k, v in net.state_dict().items()})
    with zipfile.ZipFile(tmp_path / "old.zip", "w") as archive:
        archive.writestr("phase_clone.json", json.dumps({
            "format": "hingelab phase clone 1", "observation_dim": 4, "hidden": [32, 32], "phases": list(PHASES),
            "max_phase_steps": 60, "hingelab_provenance": {"env_kwargs": {}}}))
        archive.writestr("weights.npz", weights.getvalue())
    loaded = PhaseClone.load(tmp_path / "old.zip")
    obs = np.random.default_rng(3).normal(0, 1, (2, 4))
    np.testing.assert_array_equal(loaded.predict(obs)[0], clone.predict(obs)[0])

def test_demos_without_phases_are_refused():
    from hingelab.episodes.transitions import Transitions

    transitions = Transitions(observations=np.zeros((2, 4)), actions=np.zeros((2, 5)), rewards=np.zeros(2),
                              next_observations=np.zeros((2, 4)), terminated=np.zeros(2, bool),
                              truncated=np.zeros(2, bool), infos={}, episode_index=np.zeros(2, int))
    with pytest.raises(ConfigError, match="do not record the demonstrator's phases"):
        PhaseDemos.from_transitions(transitions, where="datasets/x")


def test_train_high_phase_clone_and_eval_high(tmp_path, capsys):
    """A tiny run as a user runs it: demos with phases, the clone, its evaluation; then eval high on it."""
    from hingelab.cli.main import main
    from hingelab.episodes.dataset import Dataset
    from hingelab.training.high_level_demos import high_level_transitions

    run = tmp_path / "clone"
    assert main(["train", "high", "--learner", "phase-clone", "--prior-episodes", "2", "--clone-updates", "50",
                 "--clone-members", "2", "--net-arch", "16", "16", "--max-episode-steps", "40", "--eval-episodes", "1",
                 "--low-level", "privileged", "--no-randomize", "--out", str(run), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "Cloned the high-level policy with phase memory" in out and "50 updates" in out
    demos = high_level_transitions([run / "prior"], actions="recorded")
    assert {"demo_phase", "demo_phase_steps", "demo_next_phase"} <= set(demos.infos)
    phases = demos.infos["demo_phase"].astype(int)
    assert phases[0] == 0 and {0, 1, 2} <= set(phases.tolist())  # open, above, descend at least
    assert is_phase_clone(run / "model.zip") and is_phase_clone(run / "best_model.zip")
    clone = PhaseClone.load(run / "model.zip")
    record = clone.hingelab_provenance
    assert len(clone.nets) == 2 and record["config"]["clone_members"] == 2 and record["fit"]["members"] == 2
    assert record["low_level"] == "privileged" and record["fit"]["updates"] == 50
    assert (record["evaluation"]["env_steps"] == 0 and "git_commit" in record
            and record["env_kwargs"]["max_episode_steps"] == 40)
    metrics = pd.read_csv(run / "metrics.csv")
    assert len(metrics) == 1 and {"success_rate", "first_attempt_success_rate", "updates"} <= set(metrics.columns)
    # --resume keeps the prior and fits again from it: the same weights, one evaluation row
    first = (run / "model.zip").read_bytes()
    prior_files = sorted(p.name for p in (run / "prior").rglob("*.mcap"))
    assert main(["train", "high", "--learner", "phase-clone", "--out", str(run), "--resume", "--no-progress"]) == 0
    capsys.readouterr()
    assert sorted(p.name for p in (run / "prior").rglob("*.mcap")) == prior_files
    with zipfile.ZipFile(run / "model.zip") as a, zipfile.ZipFile(io.BytesIO(first)) as b:
        assert a.read("weights.npz") == b.read("weights.npz")
    assert len(pd.read_csv(run / "metrics.csv")) == 1

    evaluation = tmp_path / "eval"
    assert main(["eval", "high", str(run / "model.zip"), "--low-level", "privileged", "--episodes", "1",
                 "--out", str(evaluation), "--no-progress"]) == 0
    assert "model.zip" in capsys.readouterr().out
    assert len(Dataset(evaluation)) == 1


def test_phase_clone_bad_input_gets_one_line_errors(tmp_path, capsys):
    from hingelab.cli.main import main

    cases = {
        "drop --no-prior": ["--no-prior"],
        "not heuristic": ["--prior-source", "heuristic"],
    }
    for k, (message, args) in enumerate(cases.items()):
        assert main(["train", "high", "--learner", "phase-clone", *args, "--out", str(tmp_path / f"r{k}"),
                     "--no-progress"]) == 1
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1, err


def test_noisy_demos_execute_a_perturbed_velocity_and_label_the_clean_action(tmp_path):
    """--prior-action-noise: the scripted demonstrator's executed hand velocity carries the noise, its latent
    goal does not, and the clone's demos take the clean action from the step's labels."""
    from hingelab.episodes.dataset import Dataset
    from hingelab.learners.phase_clone.config import PhaseCloneConfig
    from hingelab.learners.sac.high_level_config import HighLevelTrainConfig
    from hingelab.training.high_level_demos import high_level_transitions
    from hingelab.training.prior import generate_prior

    config = PhaseCloneConfig(low_level="privileged", randomize=False, max_episode_steps=30, prior_episodes=1,
                              prior_action_noise=0.2, seed=3)
    root, = generate_prior(tmp_path / "prior", config, "noisy", progress=False)
    assert Dataset(root).card.config["action_noise"] == 0.2
    transitions = high_level_transitions([root], actions="recorded")
    clean = np.stack([transitions.infos[f"demo_action_{i}"] for i in range(5)], axis=1)
    executed = np.asarray(transitions.actions)
    np.testing.assert_allclose(executed[:, :2], clean[:, :2], atol=1e-6)  # the latent goal as commanded
    offset = executed[:, 2:] - clean[:, 2:]
    inside = np.abs(executed[:, 2:]) < 1  # clipped components say nothing of the noise
    assert 0.1 < offset[inside].std() < 0.3
    np.testing.assert_allclose(PhaseDemos.from_transitions(transitions).actions, clean, atol=1e-6)
    with pytest.raises(ConfigError, match="--prior-action-noise"):
        HighLevelTrainConfig(prior_action_noise=0.1, prior_source="heuristic")


def test_the_fit_does_not_depend_on_the_order_of_the_demo_steps():
    """A dataset lists its episodes by file name, partly random: the same demos in another order fit the same
    weights."""
    demos = _timer_demos(episodes=6)
    order = np.random.default_rng(1).permutation(len(demos))
    shuffled = PhaseDemos(*(getattr(demos, f)[order] for f in
                            ("observations", "actions", "phases", "steps", "next_phases")))
    a, _ = fit_phase_clone(demos, (8,), 20, 16, 1e-2, seed=0)
    b, _ = fit_phase_clone(shuffled, (8,), 20, 16, 1e-2, seed=0)
    for x, y in zip(a.state_dict().values(), b.state_dict().values()):
        np.testing.assert_array_equal(x.numpy(), y.numpy())

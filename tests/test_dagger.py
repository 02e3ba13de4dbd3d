"""DAgger over the phase clone (``train high --learner dagger``).

The scripted demonstrator shadowing a clone takes the clone's memory as its phase before it decides, labels the
step with its own action and next phase, and leaves the episode as the clone alone would run it; a tiny run
through the command line records labelled rounds, fits from the last round's nets (keeping their
standardization), evaluates each round, and resumes a cut-off round to the same weights; bad input gets
one-line errors."""

from __future__ import annotations

import io
import zipfile

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest

from hingelab.learners.dagger.rollouts import ShadowedClone, sync_phase
from hingelab.learners.phase_clone.fit import PhaseDemos, fit_phase_clone
from hingelab.policies import ModelPolicy
from hingelab.policies.phase_clone import PHASES, PhaseClone
from hingelab.rollouts.high_level import FailureReasonWrapper, run_episode

TINY = ["--low-level", "privileged", "--no-randomize", "--max-episode-steps", "40", "--eval-episodes", "1",
        "--no-progress"]


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A base fitted on 2 scripted demos, then 2 rounds of 2 rollouts each."""
    from hingelab.cli.main import main

    run = tmp_path_factory.mktemp("dagger") / "run"
    assert main(["train", "high", "--learner", "dagger", "--prior-episodes", "2", "--clone-updates", "40",
                 "--clone-members", "2", "--net-arch", "16", "16", "--dagger-rounds", "2", "--dagger-episodes", "2",
                 "--rollout-objects", "run", "--dagger-updates", "30", "--out", str(run), *TINY]) == 0
    return run


def _env():
    return FailureReasonWrapper(gym.make("hingelab/ToolPick-v0", low_level="privileged", randomize=False,
                                         max_episode_steps=40))


def test_sync_phase_puts_the_demonstrator_in_the_clones_phase():
    from hingelab.policies.baselines import ScriptedPolicy

    env = _env()
    env.reset(seed=5)
    demonstrator = ScriptedPolicy()
    demonstrator.reset(env, 5)
    heuristic = demonstrator.heuristic
    sync_phase(heuristic, PHASES.index("close"), 7, 0.31)
    assert heuristic.phase == "close" and heuristic.phase_steps == 7 and heuristic.hinge_cmd == 0.31
    sync_phase(heuristic, PHASES.index("close"), 9, 0.5)  # no change of phase: the ramp goes on from its command
    assert heuristic.phase_steps == 9 and heuristic.hinge_cmd == 0.31
    sync_phase(heuristic, PHASES.index("carry"), 0, 0.5)
    assert heuristic.hinge_cmd == pytest.approx(heuristic.contact_theta - heuristic.squeeze)
    heuristic.phase = "hold"  # carrying at the target counts as carrying: left as it is
    sync_phase(heuristic, PHASES.index("carry"), 3, 0.5)
    assert heuristic.phase == "hold" and heuristic.phase_steps == 3
    sync_phase(heuristic, PHASES.index("above"), 0, 0.5)
    assert heuristic.phase == "above" and heuristic.hinge_cmd == heuristic.open_theta
    env.close()


def test_the_shadow_labels_without_changing_the_clones_episode(tiny_run):
    clone = PhaseClone.load(tiny_run / "base.zip")
    env = _env()
    alone = run_episode(ModelPolicy(clone), env, 11)
    shadowed = ShadowedClone(clone)
    obs, _ = env.reset(seed=11)
    shadowed.reset(env, 11)
    memory, steps, total = None, 0, 0.0
    while True:
        expected, memory = clone.predict(obs, state=memory)
        before = shadowed.memory
        action = shadowed.act(env, obs)
        np.testing.assert_array_equal(action, expected)  # the clone drives
        labels = shadowed.labels
        held = (0, 0) if before is None else tuple(np.asarray(before).reshape(2))
        assert (labels["demo_phase"], labels["demo_phase_steps"]) == held  # its own memory is the input
        assert labels["dagger_executed_demonstrator"] == 0.0 and 0 <= labels["demo_next_phase"] < len(PHASES)
        assert all(-1 <= labels[f"demo_action_{i}"] <= 1 for i in range(5))
        obs, reward, terminated, truncated, _ = env.step(action)
        steps, total = steps + 1, total + float(reward)
        if terminated or truncated:
            break
    assert steps == alone["length"] and total == pytest.approx(alone["return"], abs=1e-9)
    # the demonstrator executing every step: its labelled action is the executed one
    driven = ShadowedClone(clone, demonstrator_share=1.0)
    obs, _ = env.reset(seed=11)
    driven.reset(env, 11)
    for _ in range(5):
        action = driven.act(env, obs)
        np.testing.assert_array_equal(action, [driven.labels[f"demo_action_{i}"] for i in range(5)])
        assert driven.labels["dagger_executed_demonstrator"] == 1.0
        obs, *_ = env.step(action)
    env.close()


def test_a_tiny_run_records_labelled_rounds_and_fits_on_from_the_last_nets(tiny_run):
    from hingelab.training.high_level_demos import high_level_transitions

    metrics = pd.read_csv(tiny_run / "metrics.csv")
    assert metrics["round"].tolist() == [0, 1, 2] and metrics["env_steps"].is_monotonic_increasing
    assert (metrics["round_steps"].iloc[1:] > 0).all() and metrics["env_steps"].iloc[-1] == metrics["round_steps"].sum()
    for k in (1, 2):
        rollouts = high_level_transitions([tiny_run / "rounds" / str(k)], actions="recorded")
        assert len(rollouts) == metrics["round_steps"].iloc[k]
        labels = PhaseDemos.from_transitions(rollouts)  # the clone's memory in, the demonstrator's labels out
        assert labels.phases[0] == 0 and labels.steps[0] == 0
        assert not np.allclose(labels.actions, rollouts.actions)  # labelled with the demonstrator's action
    base, last = PhaseClone.load(tiny_run / "base.zip"), PhaseClone.load(tiny_run / "model.zip")
    assert len(last.nets) == 2
    for a, b in zip(base.nets, last.nets):  # went on from the base's nets: their standardization kept
        np.testing.assert_array_equal(a.mean.numpy(), b.mean.numpy())
        np.testing.assert_array_equal(a.std.numpy(), b.std.numpy())
    record = last.hingelab_provenance
    assert record["learner"] == "dagger" and record["dagger"]["round"] == 2
    assert record["dagger"]["labelled_steps"] == metrics["env_steps"].iloc[-1] and record["fit"]["updates"] == 30
    assert record["dagger"]["base"]["how"] == "fit" and "git_commit" in record
    assert record["config"]["object"] == "family:picksets"  # evaluated on the 12 sets, one per episode
    assert (tiny_run / "best_model.zip").exists()


def test_a_cut_off_round_resumes_to_the_same_clone(tiny_run, tmp_path, capsys):
    import shutil

    from hingelab.cli.main import main

    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    finished = (run / "rounds" / "round_2.zip").read_bytes()
    (run / "rounds" / "round_2.zip").unlink()  # killed after round 2's rollouts, before its clone was saved
    for episode in list((run / "rounds" / "2" / "episodes").glob("*.mcap"))[:1]:
        episode.unlink()
    metrics = pd.read_csv(run / "metrics.csv")
    metrics.iloc[:2].to_csv(run / "metrics.csv", index=False)
    assert main(["train", "high", "--learner", "dagger", "--out", str(run), "--resume", "--no-progress"]) == 0
    capsys.readouterr()
    with zipfile.ZipFile(run / "rounds" / "round_2.zip") as a, zipfile.ZipFile(io.BytesIO(finished)) as b:
        resumed, uninterrupted = (np.load(io.BytesIO(z.read("weights.npz"))) for z in (a, b))
        assert resumed.files == uninterrupted.files  # (the npz's own zip headers hold their write times)
        for name in resumed.files:
            np.testing.assert_array_equal(resumed[name], uninterrupted[name])
    assert pd.read_csv(run / "metrics.csv")["round"].tolist() == [0, 1, 2]


def test_fit_going_on_from_a_net_keeps_it_and_its_standardization():
    rng = np.random.default_rng(0)
    n = 64
    demos = PhaseDemos(rng.normal(size=(n, 4)).astype(np.float32), rng.uniform(-1, 1, (n, 5)).astype(np.float32),
                       np.zeros(n, np.int64), np.zeros(n, np.int64), np.zeros(n, np.int64))
    start, _ = fit_phase_clone(demos, (8,), 20, 16, 1e-2, seed=0)
    shifted = PhaseDemos.concat([demos, PhaseDemos(demos.observations + 5, demos.actions, demos.phases, demos.steps,
                                                   demos.next_phases)])
    assert len(shifted) == 2 * n
    net, fit = fit_phase_clone(shifted, (99,), 10, 16, 1e-3, seed=1, start=start)
    assert net is not start and net.hidden == (8,) and fit["updates"] == 10
    np.testing.assert_array_equal(net.mean.numpy(), start.mean.numpy())
    assert any(not np.array_equal(a.detach().numpy(), b.detach().numpy())
               for a, b in zip(net.parameters(), start.parameters()))
    from hingelab.errors import ConfigError

    wide = PhaseDemos(np.zeros((n, 6), np.float32), demos.actions, demos.phases, demos.steps, demos.next_phases)
    with pytest.raises(ConfigError, match="4-D observations"):
        fit_phase_clone(wide, (8,), 1, 16, 1e-3, seed=0, start=start)


def test_dagger_bad_input_gets_one_line_errors(tmp_path, capsys, tiny_run):
    from hingelab.cli.main import main

    not_a_clone = tmp_path / "notes.zip"
    not_a_clone.write_bytes(b"not a zip")
    cases = {
        "--prior-source scripted": ["--prior-source", "heuristic"],
        "not a readable phase-clone checkpoint": ["--base", str(not_a_clone)],
        "no file at": ["--base", str(tmp_path / "missing.zip")],
        "tool_position": ["--base", str(tiny_run / "base.zip"), "--from", str(tiny_run / "prior"),
                          "--env-kwargs", '{"tool_position": "relative"}'],
        "invalid dagger training config": ["--dagger-rounds", "0"],
    }
    for k, (message, args) in enumerate(cases.items()):
        # sizes that keep a run short should a case wrongly start one
        code = main(["train", "high", "--learner", "dagger", "--prior-episodes", "1", "--clone-updates", "1",
                     "--dagger-episodes", "1", "--dagger-updates", "1", "--rollout-objects", "run", *args, *TINY,
                     "--out", str(tmp_path / f"r{k}")])
        err = capsys.readouterr().err.strip()
        assert code != 0 and message in err and len(err.splitlines()) == 1, (message, err)


def test_over_a_given_base_the_run_observes_as_the_base_was_trained():
    from hingelab.learners.dagger.config import DaggerConfig

    shipped = DaggerConfig(base="shipped")  # the shipped policy: the extent and the relative tool pose
    assert shipped.env_kwargs == {"observe_extent": True, "tool_position": "relative"}
    told = DaggerConfig(base="shipped", env_kwargs={"tool_position": "observed"})  # --env-kwargs wins (then refused
    assert told.env_kwargs == {"observe_extent": True, "tool_position": "observed"}  # by the run, as above)
    assert DaggerConfig(base="fit").env_kwargs == {}

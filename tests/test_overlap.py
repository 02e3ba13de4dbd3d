"""Collection overlapped with learning (``--overlap``, ``hingelab.learners.sac.overlap``): the lag bounds
on dummy envs (every update runs while an env step is in flight, on a buffer that lacks only that step;
the policy acts with the weights the last update left), the same counters as SB3's serial loop, and on
``train low``: the flag recorded in config.json, kept by ``--resume``, and an exact resume."""

from __future__ import annotations

import json
import shutil

import gymnasium as gym
import pandas as pd
import pytest
import torch
from stable_baselines3.common.vec_env import DummyVecEnv

from hingelab.cli.main import main
from hingelab.errors import ConfigError
from hingelab.learners.residual.algorithm import ResidualSAC
from hingelab.learners.sac.demo_sac import DemoSAC
from hingelab.learners.sac.fast_sac import FastSAC
from hingelab.learners.sac.low_level_config import LowLevelTrainConfig
from hingelab.learners.sac.overlap import BUFFER_LAG_ENV_STEPS, POLICY_LAG_UPDATES, OverlappedLearning, lag_record
from hingelab.training import checkpoints as ckpt


def _actor_weights(model) -> list[torch.Tensor]:
    return [p.detach().clone() for p in model.actor.parameters()]


def _instrumented_run(n_envs: int, gradient_steps: int, overlap: bool, steps: int = 240, learning_starts: int = 40):
    """A FastSAC run on Pendulum with every env step, update and action logged."""
    venv = DummyVecEnv([lambda: gym.make("Pendulum-v1")] * n_envs)
    model = FastSAC("MlpPolicy", venv, learning_starts=learning_starts, batch_size=16, gradient_steps=gradient_steps,
                    seed=0, device="cpu", policy_kwargs={"net_arch": [16]})
    model.overlap = overlap
    log = {"sent": 0, "in_flight": False, "updates": [], "actions": [], "weights": _actor_weights(model)}
    step_async, step_wait, train, sample_action = venv.step_async, venv.step_wait, model.train, model._sample_action

    def logged_step_async(actions):
        log["sent"] += n_envs
        log["in_flight"] = True
        step_async(actions)

    def logged_step_wait():
        out = step_wait()
        log["in_flight"] = False
        return out

    def logged_train(gradient_steps, batch_size=64):
        log["updates"].append({"stored": model.replay_buffer.size() * n_envs, "sent": log["sent"],
                               "num_timesteps": model.num_timesteps, "in_flight": log["in_flight"],
                               "gradient_steps": gradient_steps})
        train(gradient_steps=gradient_steps, batch_size=batch_size)
        log["weights"] = _actor_weights(model)  # the newest weights

    def logged_sample_action(*args, **kwargs):
        newest = all(torch.equal(a, b) for a, b in zip(_actor_weights(model), log["weights"]))
        log["actions"].append({"num_timesteps": model.num_timesteps, "updates": model._n_updates, "newest": newest})
        return sample_action(*args, **kwargs)

    venv.step_async, venv.step_wait = logged_step_async, logged_step_wait
    model.train, model._sample_action = logged_train, logged_sample_action
    model.learn(steps)
    return model, log


def _due(num_timesteps: int, n_envs: int, gradient_steps: int, learning_starts: int) -> int:
    """Updates SB3's serial loop has run once it has stored ``num_timesteps`` transitions (train_freq 1)."""
    return gradient_steps * sum(1 for k in range(1, num_timesteps // n_envs + 1) if k * n_envs > learning_starts)


@pytest.mark.parametrize("n_envs,gradient_steps", [(1, 1), (1, 2), (2, 1)])
def test_overlapped_updates_stay_within_their_lag_bounds(n_envs, gradient_steps):
    steps, learning_starts = 240, 40
    model, log = _instrumented_run(n_envs, gradient_steps, overlap=True, steps=steps, learning_starts=learning_starts)
    *during, last = log["updates"]
    assert during and all(u["in_flight"] for u in during)  # each update ran while an env step was being computed
    assert not last["in_flight"] and last["num_timesteps"] == steps  # but the last one, after the last step
    for u in log["updates"]:
        # the buffer holds every stored transition: it lacks at most the env step in flight
        assert u["stored"] == u["num_timesteps"] >= u["sent"] - BUFFER_LAG_ENV_STEPS * n_envs
    for a in log["actions"]:
        assert a["newest"]  # the policy acts with the weights the last update left: policy lag 0 updates
        # against the serial loop, the actions miss at most one env step's updates
        behind = _due(a["num_timesteps"], n_envs, gradient_steps, learning_starts) - a["updates"]
        assert 0 <= behind <= BUFFER_LAG_ENV_STEPS * gradient_steps
    assert any(a["updates"] for a in log["actions"])  # the policy acted after learning
    # SB3's counters and the number of updates are the serial loop's
    serial, serial_log = _instrumented_run(n_envs, gradient_steps, overlap=False, steps=steps,
                                           learning_starts=learning_starts)
    assert model.num_timesteps == serial.num_timesteps == steps
    assert model._n_updates == serial._n_updates == _due(steps, n_envs, gradient_steps, learning_starts)
    assert model._episode_num == serial._episode_num
    assert not any(u["in_flight"] for u in serial_log["updates"])


def test_every_fast_sac_learner_can_overlap():
    assert all(issubclass(cls, OverlappedLearning) for cls in (FastSAC, DemoSAC, ResidualSAC))
    with pytest.raises(ConfigError, match="--overlap is fast_sac's training loop"):
        LowLevelTrainConfig(overlap=True, algorithm="sac")


TINY_FLAGS = ["--steps", "120", "--envs", "1", "--max-episode-steps", "10", "--learning-starts", "30",
              "--batch-size", "16", "--buffer-size", "2000", "--net-arch", "32", "32", "--eval-every", "60",
              "--eval-goals", "1", "--checkpoint-every", "30", "--keep-checkpoints", "10", "--no-progress"]


def _weights(path) -> dict:
    return FastSAC.load(path, device="cpu").policy.state_dict()


def test_overlap_is_recorded_resumed_and_resumes_exactly(tmp_path, capsys):
    run = tmp_path / "overlapped"
    assert main(["train", "low", *TINY_FLAGS, "--overlap", "--out", str(run)]) == 0
    doc = json.loads((run / "config.json").read_text())
    assert doc["config"]["overlap"] is True
    assert doc["training_loop"] == lag_record(True) == {"overlap": True, "buffer_lag_env_steps": BUFFER_LAG_ENV_STEPS,
                                                        "policy_lag_updates": POLICY_LAG_UPDATES}
    states = {p: ckpt.read_state(p) for p in ckpt.checkpoint_dirs(run)}
    # a checkpoint after learning_starts holds the updates of its last step, still to run
    assert all(s["pending_updates"] == (1 if s["model"]["num_timesteps"] > 30 else 0)
               for p, s in states.items() if s["model"]["num_timesteps"] < 120)
    assert states[ckpt.latest_checkpoint(run)]["pending_updates"] == 0  # the end runs them
    boundary = [p for p, s in states.items() if not s["mid_episode"] and 30 < s["model"]["num_timesteps"] < 120]
    assert boundary, "no checkpoint at an episode boundary after learning started"
    copy = tmp_path / "copy"
    shutil.copytree(run, copy)
    for later in ckpt.checkpoint_dirs(copy):
        if later.name > boundary[0].name:
            shutil.rmtree(later)
    (copy / "model.zip").unlink()
    # --resume keeps the run's --overlap and refuses to drop it
    assert main(["train", "low", "--out", str(copy), "--resume", "--no-overlap", "--no-progress"]) == 1
    assert "--overlap (overlap=False, the run's True)" in capsys.readouterr().err
    assert main(["train", "low", "--out", str(copy), "--resume", "--no-progress"]) == 0
    a, b = _weights(run / "model.zip"), _weights(copy / "model.zip")
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    before, after = (pd.read_csv(p / "metrics.csv")[["env_steps", "success_rate", "return"]] for p in (run, copy))
    pd.testing.assert_frame_equal(before, after)

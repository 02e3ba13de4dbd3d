"""Checkpoints load without running code: a booby-trapped encoder and a booby-trapped SAC zip (whose
unpickling would create a file) are refused or loaded without that pickle ever running."""

from __future__ import annotations

import base64
import json
import os
import pickle
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from hingelab.errors import ConfigError

ASSETS = Path(__file__).resolve().parents[1] / "assets" / "checkpoints"


class Trap:
    """Unpickling this creates ``marker`` (what a hostile checkpoint would do instead)."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (os.makedirs, (self.marker,))


def test_a_booby_trapped_encoder_is_refused_and_nothing_runs(tmp_path):
    from hingelab.perception.encoder import load_encoder

    marker = tmp_path / "ran"
    raw = torch.load(ASSETS / "encoder.pt", map_location="cpu", weights_only=True)
    path = tmp_path / "encoder.pt"
    torch.save({**raw, "note": Trap(marker)}, path)
    with pytest.raises(ConfigError, match="not loaded"):
        load_encoder(path)
    assert not marker.exists()


def _trap_zip(source: Path, target: Path, marker: Path) -> None:
    """``source`` with every pickled entry of its data replaced by the trap."""
    with zipfile.ZipFile(source) as archive:
        entries = {name: archive.read(name) for name in archive.namelist()}
    data = json.loads(entries["data"])
    payload = base64.b64encode(pickle.dumps(Trap(marker))).decode()
    for value in data.values():
        if isinstance(value, dict) and ":serialized:" in value:
            value[":serialized:"] = payload
    entries["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(target, "w") as archive:
        for name, content in entries.items():
            archive.writestr(name, content)


def _tiny_high_level_sac(path: Path) -> Path:
    """A SAC zip of ToolPick-v0's spaces (14-D observation, 5-D action), untrained."""
    import gymnasium as gym
    from stable_baselines3 import SAC

    class Spaces(gym.Env):
        observation_space = gym.spaces.Box(-np.inf, np.inf, (14,), np.float64)
        action_space = gym.spaces.Box(-1.0, 1.0, (5,), np.float32)

    SAC("MlpPolicy", Spaces(), buffer_size=10, device="cpu", seed=0, policy_kwargs={"net_arch": [16, 16]}).save(path)
    return path


def test_a_booby_trapped_sac_zip_loads_without_its_pickles_running(tmp_path):
    from stable_baselines3 import SAC

    from hingelab.policies.high_level import load_high_level_checkpoint

    marker = tmp_path / "ran"
    trapped = tmp_path / "high_level.zip"
    source = _tiny_high_level_sac(tmp_path / "sac.zip")
    _trap_zip(source, trapped, marker)
    model = load_high_level_checkpoint(trapped)
    assert not marker.exists()  # none of its pickled entries was unpickled
    shipped = load_high_level_checkpoint(source)
    x = np.random.default_rng(0).normal(size=(16, 14))
    assert np.array_equal(model.predict(x, deterministic=True)[0], shipped.predict(x, deterministic=True)[0])
    with pytest.raises(Exception):  # what stable-baselines3's own loader would have done (here, refused)
        SAC.load(trapped, device="cpu")
    assert marker.exists()  # ... after running the trap: the reason not to use it


def test_a_sac_zip_with_a_pickle_among_its_tensors_is_refused(tmp_path):
    from hingelab.policies.low_level import load_sac_checkpoint

    marker = tmp_path / "ran"
    trapped = tmp_path / "low_level.zip"
    shutil.copy(ASSETS / "low_level.zip", trapped)
    with zipfile.ZipFile(trapped, "a") as archive:
        import io

        buffer = io.BytesIO()
        torch.save({"log_ent_coef": Trap(marker)}, buffer)
        archive.writestr("pytorch_variables.pth", buffer.getvalue())  # a later duplicate name wins on read
    with pytest.raises(ConfigError, match="refused unread"):
        load_sac_checkpoint(trapped)
    assert not marker.exists()


def test_the_shipped_checkpoints_load_safely_and_as_before():
    from stable_baselines3 import SAC

    from hingelab.policies.low_level import load_sac_checkpoint

    for name in ("low_level.zip", "low_level_closed.zip"):
        ours, theirs = load_sac_checkpoint(ASSETS / name), SAC.load(ASSETS / name, device="cpu")
        spaces = theirs.observation_space.spaces
        observation = {k: np.random.default_rng(1).normal(size=(8, *s.shape)) for k, s in spaces.items()}
        assert np.array_equal(ours.predict(observation, deterministic=True)[0],
                              theirs.predict(observation, deterministic=True)[0])


# ---------------------------------------------------------------------- a run's resume state
TINY_RUN = dict(steps=60, n_envs=1, max_episode_steps=10, learning_starts=20, batch_size=16, buffer_size=500,
                eval_every=60, eval_goals_per_region=1, checkpoint_every=30, keep_checkpoints=10,
                algorithm="sac", record=False)


@pytest.fixture(scope="module")
def tiny_low_run(tmp_path_factory):
    from hingelab.learners.sac.low_level import train_low
    from hingelab.learners.sac.low_level_config import LowLevelTrainConfig

    config = LowLevelTrainConfig(**TINY_RUN)
    run = tmp_path_factory.mktemp("resume") / "run"
    train_low(config, run, progress=False)
    return config, run


def _params(path) -> dict:
    from stable_baselines3 import SAC  # the run's own final zip: trusted

    return SAC.load(path, device="cpu").policy.state_dict()


def _boundary(run: Path) -> Path:
    """A checkpoint between episodes (resuming from it continues exactly), before the last step."""
    from hingelab.training import checkpoints as ckpt

    return next(p for p in ckpt.checkpoint_dirs(run) if not ckpt.read_state(p)["mid_episode"]
                and 0 < ckpt.read_state(p)["model"]["num_timesteps"] < TINY_RUN["steps"])


def _resume_from(run: Path, step: Path, target: Path) -> Path:
    """A copy of ``run`` cut back to checkpoint ``step``."""
    from hingelab.training import checkpoints as ckpt

    shutil.copytree(run, target)
    for later in ckpt.checkpoint_dirs(target):
        if later.name > step.name:
            shutil.rmtree(later)
    (target / "model.zip").unlink()
    return target / "checkpoints" / step.name


def test_a_runs_checkpoints_hold_no_pickles(tiny_low_run):
    from hingelab.training import checkpoints as ckpt

    _, run = tiny_low_run
    for step in ckpt.checkpoint_dirs(run):
        assert sorted(p.name for p in step.iterdir()) == ["model.zip", "replay_buffer.npz", "state.json"]
        with np.load(step / ckpt.BUFFER_FILE, allow_pickle=False) as saved:  # no object arrays in it
            assert all(saved[key].dtype != object for key in saved.files)
        json.loads((step / ckpt.STATE_FILE).read_text())


def test_resume_reads_no_pickle_of_a_booby_trapped_checkpoint(tiny_low_run, tmp_path):
    """The checkpoint's model.zip with every pickled entry a trap: the run resumes, exactly, and
    nothing ran (resume takes only its tensors and its plain counters)."""
    from hingelab.learners.sac.low_level import train_low
    from hingelab.training import checkpoints as ckpt

    config, run = tiny_low_run
    marker = tmp_path / "ran"
    step = _resume_from(run, _boundary(run), tmp_path / "copy")
    _trap_zip(step / ckpt.MODEL_FILE, step / "trapped.zip", marker)
    (step / "trapped.zip").replace(step / ckpt.MODEL_FILE)
    train_low(config, tmp_path / "copy", resume=True, progress=False)
    assert not marker.exists()
    ours, theirs = _params(tmp_path / "copy" / "model.zip"), _params(run / "model.zip")
    assert all(torch.equal(ours[k], theirs[k]) for k in theirs)


def _as_older_hingelab(step: Path, config, buffer_from: Path, marker: Path | None) -> None:
    """Rewrite a checkpoint the way hingelab wrote them before plain resume state (pickles); with
    ``marker``, its state.pkl is a trap."""
    from hingelab.learners.sac.low_level import LowLevelRun
    from hingelab.training import checkpoints as ckpt

    state = ckpt.read_state(step)
    rng = state.pop("rng")
    state.pop("episodes")
    state["num_timesteps"] = state.pop("model")["num_timesteps"]
    state["rng"] = {"torch": torch.tensor(rng["torch"], dtype=torch.uint8),
                    "numpy": (rng["numpy"][0], np.asarray(rng["numpy"][1], dtype=np.uint32), *rng["numpy"][2:]),
                    "python": (rng["python"][0], tuple(rng["python"][1]), rng["python"][2])}
    resumed = LowLevelRun(config, buffer_from, resume=True, progress=False).setup()
    resumed.env.close()
    resumed.close_evaluator()
    (step / "replay_buffer.pkl").write_bytes(pickle.dumps(resumed.model.replay_buffer))
    (step / "state.pkl").write_bytes(pickle.dumps(Trap(marker) if marker else state))
    (step / ckpt.STATE_FILE).unlink()
    (step / ckpt.BUFFER_FILE).unlink()


def test_an_older_pickled_checkpoint_is_refused_unread_and_converted_on_request(tiny_low_run, tmp_path, capsys):
    from hingelab.cli.main import main
    from hingelab.learners.sac.low_level import train_low

    config, run = tiny_low_run
    first = _boundary(run)
    reference = _resume_from(run, first, tmp_path / "reference")  # a plain copy, to read the buffer from
    marker = tmp_path / "ran"
    trapped = _resume_from(run, first, tmp_path / "trapped")
    _as_older_hingelab(trapped, config, tmp_path / "reference", marker)
    with pytest.raises(ConfigError, match="older hingelab.*checkpoints convert"):
        train_low(config, tmp_path / "trapped", resume=True, progress=False)
    assert not marker.exists()
    # a trusted one: `checkpoints convert RUNDIR` rewrites it, and the run resumes exactly
    old = _resume_from(run, first, tmp_path / "old")
    _as_older_hingelab(old, config, tmp_path / "reference", None)
    assert main(["checkpoints", "convert", str(tmp_path / "old")]) == 0
    assert "1 pickled checkpoint" in capsys.readouterr().out
    assert sorted(p.name for p in old.iterdir()) == ["model.zip", "replay_buffer.npz", "state.json"]
    train_low(config, tmp_path / "old", resume=True, progress=False)
    ours, theirs = _params(tmp_path / "old" / "model.zip"), _params(run / "model.zip")
    assert all(torch.equal(ours[k], theirs[k]) for k in theirs)
    assert reference.exists()


def test_a_phase_clone_with_a_pickle_among_its_weights_is_refused(tmp_path):
    """The phase clone's weights are plain arrays: an object array (a pickle) among them is refused unread."""
    import io

    from hingelab.policies.high_level import load_high_level_checkpoint

    marker = tmp_path / "ran"
    with zipfile.ZipFile(ASSETS / "high_level.zip") as archive:
        meta = archive.read("phase_clone.json")
    weights = io.BytesIO()
    np.savez(weights, mean=np.array([Trap(marker)], dtype=object))
    with zipfile.ZipFile(tmp_path / "trapped.zip", "w") as archive:
        archive.writestr("phase_clone.json", meta)
        archive.writestr("weights.npz", weights.getvalue())
    with pytest.raises(ConfigError, match="not a readable phase-clone checkpoint"):
        load_high_level_checkpoint(tmp_path / "trapped.zip")
    assert not marker.exists()

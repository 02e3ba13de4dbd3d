"""A Minari export states the env's spaces (bounds and dtype), its requirements and an id from the dataset's
folder, and ``recover_environment()`` gives an env with those spaces in a process that never imported hingelab."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from hingelab.episodes import create_dataset
from hingelab.episodes.dataset import Dataset
from hingelab.episodes.export import export_minari
from hingelab.tasks import TOOL_PICK_ID, TOOL_SHAPE_ID, task_spaces

STEPS = 4
PLATFORM = Path(__file__).resolve().parents[1] / "platform"


@pytest.fixture(scope="module")
def demo_heuristic(tmp_path_factory):
    """One ToolPick-v0 heuristic episode (actions recorded as float64), in a folder renamed after it was made (its
    card keeps the first name)."""
    from hingelab.rollouts.heuristic_demos import HeuristicRunConfig, generate_heuristic_dataset

    parent = tmp_path_factory.mktemp("demo")
    generate_heuristic_dataset(parent / "demo-low-level", HeuristicRunConfig(episodes=1, seed=3,
                                                                             max_episode_steps=STEPS), progress=False)
    root = (parent / "demo-low-level").rename(parent / "demo_heuristic")
    assert Dataset(root).card.name == "demo-low-level"
    return root


@pytest.fixture(scope="module")
def shape_eval(tmp_path_factory):
    """One ToolShape-v0 episode (a goal env: Dict observations), as ``hingelab eval low`` records it."""
    from hingelab.rollouts.low_level import make_eval_env

    root = tmp_path_factory.mktemp("shape") / "shape_eval"
    env_args = {"randomize": False, "max_episode_steps": STEPS}
    create_dataset(root, name="eval-low", source="low_level_evaluation", config={"env": env_args}, seed=0)
    env = make_eval_env(env_args, record_dir=root)
    env.reset(seed=1)
    done, rng = False, np.random.default_rng(0)
    while not done:
        _, _, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 9).astype(np.float32))
        done = terminated or truncated
    env.close()
    return root


def _load(root: Path, dataset_id: str, monkeypatch):
    import minari

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    return minari.load_dataset(dataset_id)


@pytest.mark.parametrize("name, env_id", [("demo_heuristic", TOOL_PICK_ID), ("shape_eval", TOOL_SHAPE_ID)])
def test_spaces_requirements_and_id_are_the_envs(name, env_id, request, tmp_path, monkeypatch):
    root = request.getfixturevalue(name)
    result = export_minari(Dataset(root), tmp_path / "minari")
    dataset_id = f"hingelab/{name}-v0"  # the folder's name, not the card's
    assert result.path == tmp_path / "minari" / "hingelab" / f"{name}-v0"
    loaded = _load(tmp_path / "minari", dataset_id, monkeypatch)
    assert loaded.spec.dataset_id == dataset_id
    observation_space, action_space = task_spaces(env_id)
    assert loaded.action_space == action_space and loaded.observation_space == observation_space
    assert loaded.action_space.dtype == np.float32
    assert (loaded.action_space.low == -1).all() and (loaded.action_space.high == 1).all()
    metadata = json.loads((result.path / "data" / "metadata.json").read_text())
    assert metadata["requirements"] == ["hingelab>=0.1.0"]
    assert loaded.storage.metadata["requirements"] == ["hingelab>=0.1.0"]  # what recover_environment checks
    episodes = list(loaded.iterate_episodes())
    assert len(episodes) == 1
    for episode in episodes:
        assert episode.actions.dtype == np.float32 and loaded.action_space.contains(episode.actions[0])
        observations = episode.observations if isinstance(episode.observations, dict) else {
            "observation": episode.observations}
        # NaN-free: what Minari's users read (infos row 0 is the reset's, which hingelab does not record)
        for value in (*observations.values(), episode.actions, episode.rewards):
            assert np.isfinite(value).all()
        for key, value in episode.infos.items():
            if key not in ("tool_points", "tool_points_valid"):
                assert np.isfinite(value[1:]).all(), key
        assert episode.infos["tool_points_valid"].all() and np.isfinite(episode.infos["tool_points"]).all()


def test_dataset_id_flag_still_names_it(shape_eval, tmp_path, monkeypatch):
    result = export_minari(Dataset(shape_eval), tmp_path / "m", dataset_id="lab/shapes-v2")
    assert result.path == tmp_path / "m" / "lab" / "shapes-v2"
    assert _load(tmp_path / "m", "lab/shapes-v2", monkeypatch).total_episodes == 1


def test_recover_environment_without_importing_hingelab_gives_the_datasets_spaces(shape_eval, tmp_path):
    """Minari rebuilds the env from the stored env_spec in a fresh process: its entry point imports hingelab,
    which registers the ids; the requirement is installed, so Minari warns about nothing."""
    export_minari(Dataset(shape_eval), tmp_path / "minari")
    script = (
        "import sys, warnings\n"
        "import minari\n"
        "assert 'hingelab' not in sys.modules\n"
        "dataset = minari.load_dataset('hingelab/shape_eval-v0')\n"
        "with warnings.catch_warnings():\n"
        "    warnings.simplefilter('error')\n"
        "    env = dataset.recover_environment()\n"
        "assert env.observation_space == dataset.observation_space, env.observation_space\n"
        "assert env.action_space == dataset.action_space, env.action_space\n"
        "assert env.spec.id == 'hingelab/ToolShape-v0'\n"
        "env.close()\n"
        "print('recovered', env.action_space)\n")
    environment = dict(os.environ, MINARI_DATASETS_PATH=str(tmp_path / "minari"),
                       PYTHONPATH=os.pathsep.join(filter(None, [str(PLATFORM), os.environ.get("PYTHONPATH")])))
    run = subprocess.run([sys.executable, "-c", script], env=environment, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "recovered Box(-1.0, 1.0, (9,), float32)" in run.stdout


def test_an_env_builds_the_spaces_task_spaces_states():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = gym.make(TOOL_SHAPE_ID, randomize=False)
    try:
        assert (env.observation_space, env.action_space) == task_spaces(TOOL_SHAPE_ID)
    finally:
        env.close()

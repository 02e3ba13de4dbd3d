"""--ray on generate heuristic, eval low and eval high: episodes as Ray tasks on a local one-node Ray write
the same dataset as local workers for the same seed."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from hingelab.cli.main import main
from hingelab.episodes.dataset import Dataset
from hingelab.episodes.reader import read_episode


def _episodes_by_seed(root):
    index = Dataset(root).index.sort_values("seed")
    return [read_episode(root / "episodes" / f) for f in index["file"]]


def _same_episodes(a_root, b_root, n: int,
                   volatile=("episode_id", "wall_time", "created", "log_time_origin_ns")) -> None:
    a, b = _episodes_by_seed(a_root), _episodes_by_seed(b_root)
    assert len(a) == len(b) == n
    for x, y in zip(a, b):
        facts_x = {k: v for k, v in x.metadata.items() if not any(s in k for s in volatile)}
        facts_y = {k: v for k, v in y.metadata.items() if not any(s in k for s in volatile)}
        assert facts_x == facts_y
        np.testing.assert_array_equal(x["/step"]["action"], y["/step"]["action"])
        np.testing.assert_array_equal(x["/step"]["reward"], y["/step"]["reward"])
        np.testing.assert_array_equal(x.points, y.points)


def test_generate_heuristic_and_eval_low_and_high_on_ray_equal_local_runs(tmp_path, capsys):
    """The three --ray commands run on one local Ray that the test starts (``ray_session`` uses a Ray already
    initialized as it is; the fan-out's workers serve one run after another): one Ray start and one set of
    worker start-ups, not three. A command starting its own local Ray and shutting it down:
    ``test_ray_resume.py`` (its ``--ray --resume`` runs in this process) and ``test_local_ray_reaper.py``.
    generate heuristic runs with one worker: in this process locally, on every core of the Ray over Ray
    (2 local worker processes write the same episodes:
    ``test_heuristic.py::test_same_seed_same_dataset_whatever_the_workers``)."""
    from hingelab.workers.ray_runtime import ray_session

    heuristic = ["generate", "heuristic", "--episodes", "3", "--seed", "5", "--no-progress"]
    low = ["eval", "low", "--baseline", "hold-still", "--episodes", "3", "--seed", "2", "--no-progress"]
    high = ["eval", "high", "--baseline", "heuristic", "--episodes", "2", "--no-progress"]
    assert main([*heuristic, "--out", str(tmp_path / "heuristic_local")]) == 0
    assert main([*low, "--out", str(tmp_path / "low_local")]) == 0
    assert main([*high, "--out", str(tmp_path / "high_local")]) == 0
    with ray_session():
        capsys.readouterr()
        assert main([*heuristic, "--out", str(tmp_path / "heuristic_ray"), "--ray"]) == 0
        assert "3 episodes" in capsys.readouterr().out
        assert main([*low, "--out", str(tmp_path / "low_ray"), "--ray"]) == 0
        assert main([*high, "--out", str(tmp_path / "high_ray"), "--ray"]) == 0
    _same_episodes(tmp_path / "heuristic_local", tmp_path / "heuristic_ray", 3)
    assert not list((tmp_path / "heuristic_ray" / "episodes").glob("*.partial"))
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "low_local" / "episodes.csv"),
                                  pd.read_csv(tmp_path / "low_ray" / "episodes.csv"))
    _same_episodes(tmp_path / "low_local", tmp_path / "low_ray", 3)
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "high_local" / "episodes.csv"),
                                  pd.read_csv(tmp_path / "high_ray" / "episodes.csv"))
    _same_episodes(tmp_path / "high_local", tmp_path / "high_ray", 2)


def test_a_ray_address_that_answers_nothing_is_one_line(tmp_path, capsys):
    out = tmp_path / "x"
    code = main(["generate", "heuristic", "--episodes", "1", "--out", str(out), "--ray", "127.0.0.1:1",
                 "--no-progress"])
    assert code == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "cannot join the Ray cluster at 127.0.0.1:1" in err


@pytest.fixture(autouse=True)
def _no_ray_left_running():
    yield
    import ray

    assert not ray.is_initialized()

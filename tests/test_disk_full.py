"""A full disk stops ``generate heuristic`` with one line (folder, free space, episodes kept), and
``--resume`` finishes the run into the same dataset an uninterrupted run writes."""

from __future__ import annotations

import errno

import numpy as np

from hingelab.cli.main import main
from hingelab.episodes import read_episode
from hingelab.episodes.dataset import Dataset
from hingelab.episodes.verify import verify_dataset

ARGS = ["generate", "heuristic", "--episodes", "4", "--seed", "3", "--no-progress"]


def fill_the_disk_on_the_third_episode(monkeypatch):
    """``EpisodeWriter.close`` raises ENOSPC on its 3rd call (as a full disk would); returns the real close."""
    from hingelab.episodes.writer import EpisodeWriter

    close, calls = EpisodeWriter.close, {"n": 0}

    def fill_up_on_the_third(self):
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError(errno.ENOSPC, "No space left on device")
        return close(self)

    monkeypatch.setattr(EpisodeWriter, "close", fill_up_on_the_third)
    return close


def _by_seed(root) -> dict:
    dataset = Dataset(root)
    return {int(seed): read_episode(dataset.episodes_dir / name)
            for seed, name in zip(dataset.index["seed"], dataset.index["file"])}


def test_disk_full_stops_cleanly_and_resume_completes_the_same_dataset(tmp_path, monkeypatch, capsys):
    from hingelab.episodes.writer import EpisodeWriter

    stopped = tmp_path / "stopped"
    close = fill_the_disk_on_the_third_episode(monkeypatch)
    assert main([*ARGS, "--out", str(stopped)]) == 1
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and str(stopped) in error and "MB free" in error
    assert "kept the 2 finished episodes of 4" in error and "--resume" in error
    good, problems = verify_dataset(stopped)
    assert len(good) == 2 and all(p.kind == "partial" for p in problems)  # the finished ones are whole

    monkeypatch.setattr(EpisodeWriter, "close", close)
    assert main([*ARGS, "--out", str(stopped)]) == 1  # without --resume the folder is refused
    assert "--resume" in capsys.readouterr().err
    assert main([*ARGS, "--out", str(stopped), "--resume"]) == 0
    assert "resumed: 2 were there" in capsys.readouterr().out
    good, problems = verify_dataset(stopped)
    assert len(good) == 4 and not problems  # the unfinished write is gone

    whole = tmp_path / "whole"
    assert main([*ARGS, "--out", str(whole)]) == 0
    resumed, uninterrupted = _by_seed(stopped), _by_seed(whole)
    assert sorted(resumed) == sorted(uninterrupted)
    ignore = {"episode_id", "created", "git_commit", "log_time_origin_ns"}  # the last: the wall clock at the start
    for seed, episode in uninterrupted.items():
        other = resumed[seed]
        assert {k: v for k, v in episode.metadata.items() if k not in ignore} == \
               {k: v for k, v in other.metadata.items() if k not in ignore}
        for topic, fields in episode.topics.items():
            for name, values in fields.items():
                assert np.array_equal(values, other.topics[topic][name], equal_nan=values.dtype.kind == "f"), \
                    (seed, topic, name)
    assert main([*ARGS, "--out", str(stopped), "--resume"]) == 0  # complete: nothing to do
    assert "nothing to do" in capsys.readouterr().out


def test_resume_refuses_other_settings(tmp_path, capsys):
    out = tmp_path / "d"
    assert main([*ARGS[:3], "1", "--seed", "3", "--no-progress", "--out", str(out)]) == 0
    assert main([*ARGS[:3], "2", "--seed", "4", "--no-progress", "--out", str(out), "--resume"]) == 1
    assert "seed" in capsys.readouterr().err


def test_eval_high_resumes_after_a_full_disk(tmp_path, monkeypatch, capsys):
    import pandas as pd

    from hingelab.episodes.writer import EpisodeWriter

    args = ["eval", "high", "--baseline", "scripted", "--low-level", "privileged", "--episodes", "4",
            "--seed", "2", "--no-progress"]
    stopped, whole = tmp_path / "stopped", tmp_path / "whole"
    close = fill_the_disk_on_the_third_episode(monkeypatch)
    assert main([*args, "--out", str(stopped)]) == 1
    error = capsys.readouterr().err.strip()
    assert "kept the 2 finished episodes of 4" in error and f"--out {stopped}" in error and "--resume" in error
    monkeypatch.setattr(EpisodeWriter, "close", close)
    assert main([*args, "--out", str(stopped), "--resume"]) == 0
    assert main([*args, "--out", str(whole)]) == 0
    ours, theirs = pd.read_csv(stopped / "episodes.csv"), pd.read_csv(whole / "episodes.csv")
    pd.testing.assert_frame_equal(ours, theirs)
    assert (stopped / "table.csv").read_text() == (whole / "table.csv").read_text()
    assert not (stopped / "episodes.partial.jsonl").exists()
    good, problems = verify_dataset(stopped)
    assert len(good) == 4 and not problems
    assert main([*args, "--out", str(stopped)]) == 1  # a finished folder is not written into again
    assert main([*args, "--out", str(stopped), "--resume"]) == 1  # nor redone by a --resume
    assert "nothing to resume" in capsys.readouterr().err
    assert len(verify_dataset(stopped)[0]) == 4

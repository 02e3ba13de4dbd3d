"""A `--ray` rollout fan-out killed mid-way (SIGKILL of the driver: episodes on disk, others half-written as
`.partial`, a Ray worker possibly finishing one after the driver is gone) and resumed at once with
`--resume` ends as the uninterrupted run: every episode seed once, the same transitions, `datasets verify`
clean."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pandas as pd
import psutil
import pytest

from hingelab.cli.main import main
from hingelab.episodes.dataset import Dataset
from hingelab.episodes.reader import read_episode
from hingelab.workers.ray_reaper import session_processes
from test_local_ray_reaper import CLEANUP_DEADLINE_S, _alive, _session_dir

VOLATILE_FIELDS = ("log_time_ns",)  # when a message was logged (wall clock); everything else is the episode's


def _digest(path: Path) -> str:
    """A content digest of an episode's transitions: every field of every topic but its log time."""
    episode = read_episode(path)
    h = hashlib.sha256()
    for topic in sorted(episode.topics):
        for name, values in sorted(episode.topics[topic].items()):
            if name in VOLATILE_FIELDS:
                continue
            values = np.ascontiguousarray(values)
            h.update(f"{topic}/{name}/{values.dtype}/{values.shape}".encode())
            h.update(values.tobytes() if values.dtype != object else repr(values.tolist()).encode())
    return h.hexdigest()


def _seeds_and_digests(root: Path) -> list[tuple[int, str]]:
    index = Dataset(root).build_index(rebuild=True)
    return sorted((int(seed), _digest(root / "episodes" / name)) for seed, name in zip(index["seed"], index["file"]))


class KilledDriver:
    """A ``--ray`` driver SIGKILLed mid-write, and its local Ray's processes at the kill. ``watch_cleanup``
    follows them from the kill on, in a thread (the test goes on: resumes at once); ``assert_cleaned_up``
    then checks what ``test_local_ray_reaper.py``'s SIGKILL test checks: no process of the killed driver's Ray
    session outlived it by more than ``CLEANUP_DEADLINE_S``, and the reaper said what it stopped."""

    def __init__(self, driver: subprocess.Popen):
        self.driver = driver
        self.tree = psutil.Process(driver.pid).children(recursive=True)
        self.session_dir = _session_dir(self.tree)
        assert self.session_dir and os.path.isdir(self.session_dir), [p.cmdline()[:1] for p in self.tree]
        ray_tree = [p for p in self.tree if p in session_processes(self.session_dir)]
        assert any("raylet" in " ".join(p.cmdline()) for p in ray_tree) and len(ray_tree) >= 4
        self.cleaned_after_s = None

    def kill_and_watch_cleanup(self) -> None:
        self.driver.send_signal(signal.SIGKILL)
        killed_at = time.time()

        def watch():
            while time.time() < killed_at + CLEANUP_DEADLINE_S:
                if not (_alive(self.tree) or session_processes(self.session_dir)):
                    self.cleaned_after_s = time.time() - killed_at
                    return
                time.sleep(0.5)

        self.watcher = threading.Thread(target=watch, daemon=True)
        self.watcher.start()
        self.driver.wait(timeout=30)

    def assert_cleaned_up(self) -> None:
        self.watcher.join(timeout=CLEANUP_DEADLINE_S + 5)
        assert self.cleaned_after_s is not None, (_alive(self.tree), session_processes(self.session_dir))
        assert _alive(self.tree) == [] and session_processes(self.session_dir) == []
        _, err = self.driver.communicate(timeout=30)  # the reaper held the stderr pipe until it finished
        assert f"the driver (pid {self.driver.pid}) of the local Ray in" in err and "leftover process(es)" in err, err


def _kill_after(argv: list[str], out: Path, finished: int) -> tuple[int, int, KilledDriver]:
    """Run ``hingelab *argv`` and SIGKILL it once ``finished`` episodes are on disk and another is being
    written; returns the finished and half-written files at the kill, and the killed driver (its Ray's
    processes followed from the kill on)."""
    driver = subprocess.Popen([sys.executable, "-m", "hingelab.cli.main", *argv], stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE, text=True)
    episodes = out / "episodes"
    deadline = time.time() + 300
    done = partial = 0
    while time.time() < deadline and driver.poll() is None:
        names = [p.name for p in episodes.iterdir()] if episodes.is_dir() else []
        done, partial = sum(n.endswith(".mcap") for n in names), sum(n.endswith(".partial") for n in names)
        if done >= finished and partial:
            break
        time.sleep(0.05)
    assert driver.poll() is None, f"it ended before the kill: raise the episodes ({driver.communicate()[1]})"
    killed = KilledDriver(driver)
    killed.kill_and_watch_cleanup()
    return done, partial, killed


def _verify_clean(root: Path, capsys) -> None:
    capsys.readouterr()
    assert main(["datasets", "verify", str(root)]) == 0
    assert not list((root / "episodes").glob("*.partial"))


@pytest.mark.slow
def test_generate_heuristic_on_ray_killed_and_resumed_equals_an_uninterrupted_run(tmp_path, capsys):
    """Slow (a minute: three commands, two local Rays). The default run covers it in parts:
    ``test_eval_on_ray_killed_and_resumed_equals_an_uninterrupted_run[high]`` (a --ray driver SIGKILLed
    mid-write, resumed at once over Ray, equal to an uninterrupted run), ``test_ray_rollouts.py::
    test_generate_heuristic_and_eval_low_and_high_on_ray_equal_local_runs`` (generate heuristic over Ray =
    local workers),
    ``test_disk_full.py::test_disk_full_stops_cleanly_and_resume_completes_the_same_dataset`` (its --resume
    = an uninterrupted run) and ``test_an_episode_still_being_written_when_resume_starts_cannot_land``
    (its resume against a worker of the killed run)."""
    common = ["generate", "heuristic", "--episodes", "6", "--seed", "9", "--workers", "2", "--no-progress"]
    out = tmp_path / "killed"
    done, partial, killed = _kill_after([*common, "--out", str(out), "--ray"], out, finished=2)
    assert done >= 2 and partial >= 1
    # resumed at once: a Ray worker of the killed run may still be finishing the episode it had
    assert main([*common, "--out", str(out), "--ray", "--resume"]) == 0
    assert main([*common, "--out", str(tmp_path / "whole")]) == 0
    resumed, whole = _seeds_and_digests(out), _seeds_and_digests(tmp_path / "whole")
    assert len(whole) == 6 and len({s for s, _ in resumed}) == len(resumed)  # every seed once
    assert resumed == whole
    _verify_clean(out, capsys)
    killed.assert_cleaned_up()


@pytest.mark.parametrize("command", [
    pytest.param(["eval", "low", "--baseline", "hold-still", "--episodes", "6", "--seed", "3"], marks=pytest.mark.slow),
    ["eval", "high", "--baseline", "heuristic", "--episodes", "5", "--seed", "3"],
], ids=["low", "high"])
def test_eval_on_ray_killed_and_resumed_equals_an_uninterrupted_run(tmp_path, capsys, command):
    """[low] is slow (a minute); eval low and eval high over Ray share the fan-out and the journal
    (``rollouts.on_ray._run``), so [high] covers it by default, with ``test_ray_rollouts.py::
    test_generate_heuristic_and_eval_low_and_high_on_ray_equal_local_runs`` for eval low over Ray itself."""
    common = [*command, "--no-progress"]
    out = tmp_path / "killed"
    done, partial, killed = _kill_after([*common, "--out", str(out), "--ray"], out, finished=2)
    assert done >= 2 and partial >= 1
    assert (out / "episodes.partial.jsonl").exists()  # the journal of the killed run
    assert main([*common, "--out", str(out), "--ray", "--resume"]) == 0
    assert main([*common, "--out", str(tmp_path / "whole")]) == 0
    resumed, whole = _seeds_and_digests(out), _seeds_and_digests(tmp_path / "whole")
    assert len(whole) == int(command[command.index("--episodes") + 1])
    assert len({s for s, _ in resumed}) == len(resumed)  # every seed once
    assert resumed == whole
    pd.testing.assert_frame_equal(pd.read_csv(out / "episodes.csv"), pd.read_csv(tmp_path / "whole" / "episodes.csv"))
    assert not (out / "episodes.partial.jsonl").exists()
    _verify_clean(out, capsys)
    killed.assert_cleaned_up()  # the local Ray died with its SIGKILLed driver (test_local_ray_reaper.py's check)


def test_an_episode_still_being_written_when_resume_starts_cannot_land(tmp_path):
    """The race the kill tests may or may not hit: a worker of the killed run (its reaper not yet done, or a
    cluster's worker before Ray kills it) still writing an episode while `--resume` plans its work. Resume
    deletes the `.partial` and runs that seed again; the old worker's final rename then fails, so the seed
    is not written twice."""
    from dataclasses import asdict

    from hingelab.episodes import create_dataset
    from hingelab.episodes.synthetic import synthetic_step, write_synthetic_episode
    from hingelab.episodes.writer import EpisodeWriter
    from hingelab.rollouts.heuristic_demos import HeuristicRunConfig, _seeds_to_run
    from hingelab.seeds import demo_seed

    config = HeuristicRunConfig(episodes=4, seed=2)
    out = tmp_path / "demos"
    create_dataset(out, name="demos", source="heuristic", config=asdict(config), seed=config.seed)
    seeds = [demo_seed(config.seed, k) for k in range(config.episodes)]
    for seed in seeds[:2]:
        write_synthetic_episode(out, seed, n_steps=5, source="heuristic")
    ghost = EpisodeWriter(out, source="heuristic", seed=seeds[2])  # the killed run's worker, mid-episode
    ghost.open()
    ghost.write_step(0.0, **synthetic_step(np.random.default_rng(0), 0, 5))
    assert _seeds_to_run(out, config, resume=True) == seeds[2:]
    with pytest.raises(FileNotFoundError):
        ghost.close()
    assert sorted(Dataset(out).build_index(rebuild=True)["seed"]) == seeds[:2]


def test_an_evaluation_resumed_keeps_only_journaled_episodes_and_a_late_writer_cannot_land(tmp_path):
    """`eval low|high --resume`: an episode finished after the journal's last line is deleted (its seed runs
    again), and one still being written by the killed run's worker cannot land after resume planned."""
    from hingelab.episodes import create_dataset
    from hingelab.episodes.synthetic import synthetic_step, write_synthetic_episode
    from hingelab.episodes.writer import EpisodeWriter
    from hingelab.rollouts.journal import EpisodeJournal, prepare_resume

    config = {"baseline": "hold-still", "episodes": 4, "seed": 3}
    out = tmp_path / "eval"
    create_dataset(out, name="eval", source="low_level_evaluation", config=config, seed=3)
    journal = EpisodeJournal(out)
    for seed in (10, 11, 12):
        write_synthetic_episode(out, seed, n_steps=5, source="low_level_evaluation")
    for seed in (10, 11):  # 12 finished, but the driver died before its row was journaled
        journal.append({"seed": seed, "success": True})
    ghost = EpisodeWriter(out, source="low_level_evaluation", seed=13)
    ghost.open()
    ghost.write_step(0.0, **synthetic_step(np.random.default_rng(0), 0, 5))
    resumed = prepare_resume(out, config, resume=True)
    assert [r["seed"] for r in resumed.rows] == [10, 11]
    with pytest.raises(FileNotFoundError):
        ghost.close()
    assert sorted(Dataset(out).build_index(rebuild=True)["seed"]) == [10, 11]


@pytest.fixture(autouse=True)
def _no_ray_left_running():
    yield
    import ray

    assert not ray.is_initialized()

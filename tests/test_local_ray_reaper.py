"""A local Ray dies with its driver: `hingelab generate heuristic --ray` SIGKILLed mid-episode leaves no
process of its Ray session behind (the reaper of ``hingelab.workers.ray_reaper`` stops them), and
a command that ends normally leaves none either."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import psutil
import pytest

from hingelab.workers.ray_reaper import session_processes

CLEANUP_DEADLINE_S = 30  # Ray's agents alone were measured living on ~100 s after the driver without the reaper


def _session_dir(processes: list[psutil.Process]) -> str | None:
    for proc in processes:
        try:
            for arg in proc.cmdline():
                if "--session_dir=" in arg or "--session-dir=" in arg:
                    return arg.split("=", 1)[1]
        except psutil.Error:
            continue
    return None


def _alive(processes: list[psutil.Process]) -> list[str]:
    left = []
    for proc in processes:
        try:
            if proc.is_running() and proc.status() != psutil.STATUS_ZOMBIE:  # is_running checks the start time
                left.append(f"{proc.pid} {proc.name()}")
        except psutil.NoSuchProcess:
            continue
    return left


@pytest.mark.slow
def test_a_sigkilled_ray_driver_leaves_no_process_of_its_session(tmp_path):
    """Slow (half a minute: a driver process, its Ray, a kill). By default
    ``test_ray_resume.py::test_eval_on_ray_killed_and_resumed_equals_an_uninterrupted_run[high]`` checks the
    same after its SIGKILL of an ``eval high --ray`` driver mid-write: the session's raylet and workers found
    by the session folder, none of them alive ``CLEANUP_DEADLINE_S`` after the kill, the reaper's message on
    the driver's stderr."""
    out = tmp_path / "demos"
    driver = subprocess.Popen(
        [sys.executable, "-m", "hingelab.cli.main", "generate", "heuristic", "--episodes", "20", "--workers", "2",
         "--seed", "4", "--out", str(out), "--ray", "--no-progress"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    episodes = out / "episodes"
    deadline = time.time() + 240
    # an episode being written by a Ray worker: the moment a kill is most likely to leave something behind
    while time.time() < deadline and driver.poll() is None:
        if episodes.is_dir() and any(episodes.iterdir()):
            break
        time.sleep(0.2)
    assert driver.poll() is None, driver.communicate()
    tree = psutil.Process(driver.pid).children(recursive=True)
    session_dir = _session_dir(tree)
    assert session_dir and os.path.isdir(session_dir), [p.cmdline()[:1] for p in tree]
    ray_tree = [p for p in tree if p in session_processes(session_dir)]
    assert any("raylet" in " ".join(p.cmdline()) for p in ray_tree) and len(ray_tree) >= 4

    driver.send_signal(signal.SIGKILL)
    deadline = time.time() + CLEANUP_DEADLINE_S
    while time.time() < deadline and (_alive(tree) or session_processes(session_dir)):
        time.sleep(0.5)
    assert _alive(tree) == [] and session_processes(session_dir) == []
    _, err = driver.communicate(timeout=30)  # the reaper held the stderr pipe until it finished
    assert f"the driver (pid {driver.pid}) of the local Ray in" in err and "leftover process(es)" in err, err


def test_a_ray_command_that_ends_normally_leaves_no_ray_process(tmp_path):
    from hingelab.workers.ray_runtime import ray_session

    with ray_session(num_cpus=1) as ray:
        session_dir = ray._private.worker.global_worker.node.get_session_dir_path()
        assert session_processes(session_dir)  # the running Ray is found by its session folder
    assert session_processes(session_dir) == []  # shut down, and the reaper swept what shutdown left
    reapers = [p for p in psutil.process_iter(["cmdline"]) if "local_ray_reaper.py" in
               " ".join(p.info["cmdline"] or []) and str(os.getpid()) in (p.info["cmdline"] or [])]
    assert reapers == []


@pytest.fixture(autouse=True)
def _no_ray_left_running():
    yield
    import ray

    assert not ray.is_initialized()

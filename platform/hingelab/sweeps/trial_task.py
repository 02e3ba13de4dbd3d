"""One sweep trial as a Ray task: ``hingelab <command> ...`` in a child process of the Ray worker.

A child process, not the command's ``main`` inside the worker: Ray keeps its worker processes for
later tasks, and a training run sets process-wide state (torch threads, RNGs, numba and MuJoCo
globals, the corrupt-file policy) that must not leak into the next trial; a crash (a MuJoCo abort,
an out-of-memory kill) ends the trial, not the worker; and the trial is exactly the command a user
would type, writing the same run folder. Its output goes to the trial's log file. The child dies
with the worker (``PR_SET_PDEATHSIG``): a sweep that is stopped, or whose driver dies, leaves no
training behind, and ``--resume`` continues it from its last checkpoint.
"""

from __future__ import annotations

import ctypes
import os
import shlex
import signal
import socket
import subprocess
import sys
import time


def _die_with_parent() -> None:  # pragma: no cover - runs in the child between fork and exec
    try:

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, int(signal.SIGTERM))  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def run_trial(argv: list[str], log_path: str, threads: int) -> dict:
    """Run ``hingelab *argv``; returns its exit code, wall time and node (nothing else goes through Ray)."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": str(threads),
           "MKL_NUM_THREADS": str(threads)}
    started = time.time()
    with open(log_path, "a") as log:
        log.write(f"== {time.strftime('%Y-%m-%dT%H:%M:%S%z')} on {socket.gethostname()}: "
                  f"hingelab {shlex.join(argv)}\n")
        log.flush()
        child = subprocess.Popen([sys.executable, "-m", "hingelab.cli.main", *argv], stdout=log,
                                 stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env,
                                 preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None)
        try:
            code = child.wait()
        except BaseException:  # the task was cancelled: the training goes with it
            child.terminate()
            try:
                child.wait(timeout=20)
            except subprocess.TimeoutExpired:
                child.kill()
            raise
    return {"returncode": code, "wall_time_s": time.time() - started, "node": socket.gethostname()}


__all__ = ["run_trial"]

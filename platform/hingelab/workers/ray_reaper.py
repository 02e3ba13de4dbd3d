"""A local Ray that dies with its driver, even a SIGKILLed one.

``ray.init()`` without an address starts a one-node Ray (GCS, raylet, agents, workers) owned by the
driver. On Linux, Ray 2.60 binds the processes it spawns itself (GCS, raylet, log monitor) to the
driver with ``PR_SET_PDEATHSIG``, so they die with it; the raylet's dashboard and runtime-env agents
notice the raylet's death within a second, but then report it to the GCS, which is dead too, and hang
in its retries: after a ``kill -9`` of ``hingelab generate --ray`` they live on for minutes,
re-parented to init, and a worker that was running an episode finished it and wrote it
before it noticed. Ray's own reaper (``ray_process_reaper.py``: a child that kills its process group on
EOF of its stdin) is off when fate-sharing is available, and it would make the driver a process-group
leader, which a command run from a terminal must not do.

So hingelab starts its own reaper: a small process in a session of its own (a terminal's Ctrl-C or a
``kill -9`` of the job's process group does not reach it), holding the read end of a pipe whose write
end only the driver has (pipes are not inherited by Ray's processes: close-on-exec). The driver sends
the session folder once ``ray.init`` returned it; when the driver dies by any signal the kernel closes
the pipe, the reaper reads EOF and stops every process of that session: a process belongs to the
session when its command line or an open file (Ray's processes log into ``SESSION/logs``) lies in the
session folder (the driver itself excepted), and its descendants go with it (a sweep trial's training
process logs to the sweep folder instead; it also dies with its worker by ``PR_SET_PDEATHSIG``).
SIGTERM first, SIGKILL after a grace period. The session folder is unique per ``ray.init``, so another
user's or another command's Ray on the same machine is never touched. On a normal exit the driver says
``released`` before closing the pipe (after ``ray.shutdown``) and the reaper only sweeps up what
shutdown left, quietly.

Why not the alternatives: no ``_system_config`` or ``RAY_*`` setting of Ray 2.60 was found that binds
the agents to the driver (``RAY_enable_pipe_based_agent_to_parent_health_check`` only changes how they
notice the raylet's death, which they already do; the hang comes after); a watchdog polling the
driver's PID has a PID-reuse race and a polling delay that the pipe's EOF has not; cleaning up on the
next start alone leaves the processes (and an episode being written) running until then. What is
left: a driver killed during ``ray.init`` itself (before it knows the session folder, 2-5 s) leaves what
Ray had started to Ray's own fate-sharing.

Run as ``python -P .../hingelab/workers/ray_reaper.py DRIVER_PID``; ``LocalRayReaper`` starts it.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import psutil

RELEASED = "released"
GRACE_S = 5.0  # SIGTERM, then SIGKILL: Ray's processes shut down in well under a second


def session_processes(session_dir: str, exclude: tuple[int, ...] = ()) -> list:
    """The live processes of the Ray session in ``session_dir`` and their descendants (``psutil.Process``)."""

    prefix = os.path.join(os.path.realpath(session_dir), "")
    found: dict[int, psutil.Process] = {}
    for proc in psutil.process_iter():
        if proc.pid in exclude or proc.pid == os.getpid():
            continue
        try:
            if any(prefix in arg or arg == prefix[:-1] for arg in proc.cmdline()) or any(
                    f.path.startswith(prefix) for f in proc.open_files()):
                found[proc.pid] = proc
                for child in proc.children(recursive=True):
                    found.setdefault(child.pid, child)
        except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
            continue
    found.pop(os.getpid(), None)
    return [p for p in found.values() if p.pid not in exclude]


def stop_session(session_dir: str, grace_s: float = GRACE_S, exclude: tuple[int, ...] = ()) -> int:
    """Stop every process of the Ray session in ``session_dir`` (SIGTERM, then SIGKILL after ``grace_s``);
    returns how many there were."""

    procs = session_processes(session_dir, exclude)
    for proc in procs:
        try:
            proc.terminate()
        except psutil.NoSuchProcess:
            pass
    _, alive = psutil.wait_procs(procs, timeout=grace_s)
    for proc in alive:
        try:
            proc.kill()
        except psutil.NoSuchProcess:
            pass
    psutil.wait_procs(alive, timeout=grace_s)
    return len(procs)


class LocalRayReaper:
    """The driver's end: ``start()`` before ``ray.init``, ``watch(session_dir)`` after it, ``release()``
    after ``ray.shutdown``."""

    def __init__(self, process: subprocess.Popen):
        self.process = process

    @classmethod
    def start(cls) -> "LocalRayReaper | None":
        if not sys.platform.startswith("linux"):
            return None  # the pipe's EOF works elsewhere too, but the session scan is only tested on Linux
        # the file itself, not ``-m``: the reaper needs psutil alone, not hingelab's imports (gymnasium, ...)
        process = subprocess.Popen(
            [sys.executable, "-P", os.path.abspath(__file__), str(os.getpid())],  # -P: not its folder on sys.path
            stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, start_new_session=True,
            close_fds=True)
        return cls(process)

    def watch(self, session_dir: str) -> None:
        self._send(os.path.realpath(session_dir))

    def release(self, timeout_s: float = 30.0) -> None:
        """A normal end: the reaper sweeps up what ``ray.shutdown`` left and exits (waited for, so the
        command ends with no process of its Ray left)."""
        self._send(RELEASED)
        try:
            self.process.stdin.close()
        except OSError:
            pass
        try:
            self.process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            pass  # it goes on on its own; the command need not wait longer

    def _send(self, line: str) -> None:
        try:
            self.process.stdin.write(line + "\n")
            self.process.stdin.flush()
        except (OSError, ValueError):
            pass  # the reaper is gone (killed by hand): Ray runs on, without the guard


def main(argv: list[str]) -> int:
    """The reaper process: waits for EOF on stdin (the driver gone), then stops the session's processes."""
    for sig in (signal.SIGINT, signal.SIGHUP):
        signal.signal(sig, signal.SIG_IGN)  # the terminal's signals are the driver's to handle
    driver_pid = int(argv[0])
    session_dir, released = None, False
    for line in sys.stdin:
        line = line.strip()
        if line == RELEASED:
            released = True
        elif line:
            session_dir = line
    if session_dir is None:
        return 0
    if not released:
        time.sleep(0.5)  # Ray's own fate-sharing first: the GCS and raylet die with the driver
    stopped = stop_session(session_dir, exclude=(driver_pid,))  # alive after a normal end, with Ray's logs open
    if stopped and not released:
        print(f"hingelab: the driver (pid {driver_pid}) of the local Ray in {session_dir} died; stopped its "
              f"{stopped} leftover process(es)", file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

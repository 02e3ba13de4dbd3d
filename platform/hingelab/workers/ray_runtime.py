"""One Ray session per command: a local one-node Ray, or a running cluster joined by address.

``ray_session(address, num_cpus)`` starts a local Ray with ``num_cpus`` CPUs (default: the
machine's cores) when ``address`` is None or ``"local"``, and joins the cluster at ``address``
otherwise (``ray start --head`` prints it, e.g. ``10.0.0.5:6379``; ``auto`` finds one started on
this machine). It shuts Ray down on the way out, so a local Ray leaves no process behind; a local Ray
is also watched by a reaper (``local_ray_reaper``) that stops it when the driver dies without shutting
it down (a SIGKILL, an out-of-memory kill). A Ray that the caller already initialized (a test's
fixture) is used as it is and left running.

Nothing phones home: usage statistics are off (``RAY_USAGE_STATS_ENABLED=0``) and the dashboard is
not started.
"""

from __future__ import annotations

import os
import signal
import socket
import threading
from contextlib import contextmanager

from hingelab.errors import ConfigError
from hingelab.workers.ray_reaper import LocalRayReaper

LOCAL = "local"
# small: tasks return summaries and paths only, never episode arrays
LOCAL_OBJECT_STORE_BYTES = 128 * 1024 * 1024


def quiet_ray_environment() -> None:
    """Usage statistics off, before ``import ray`` reads them (also inherited by Ray's processes)."""
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    os.environ.setdefault("RAY_DISABLE_DOCKER_CPU_WARNING", "1")


def import_ray():
    quiet_ray_environment()
    try:
        import ray  # optional (the test extra), and seconds to import: only a --ray command loads it
    except ModuleNotFoundError as exc:  # pragma: no cover - ray is in the test extra
        raise ConfigError("Ray is not installed: pip install -c constraints.txt -e \".[test]\" (or ray==2.60.0)") \
            from exc
    return ray


def describe(address: str | None) -> str:
    return "a local one-node Ray" if address in (None, LOCAL) else f"the Ray cluster at {address}"


@contextmanager
def ray_session(address: str | None = None, num_cpus: int | None = None):
    """Ray, initialized for the ``with`` block (see the module docstring); yields the ``ray`` module."""
    ray = import_ray()
    if ray.is_initialized():
        yield ray
        return
    common = {"include_dashboard": False, "log_to_driver": False, "logging_level": "WARNING"}
    reaper = None
    if address in (None, LOCAL):
        cpus = int(num_cpus or os.cpu_count() or 1)
        if cpus < 1:
            raise ConfigError(f"a local Ray needs at least 1 CPU, not {cpus}")
        reaper = LocalRayReaper.start()
        try:
            context = ray.init(num_cpus=cpus, object_store_memory=LOCAL_OBJECT_STORE_BYTES, **common)
        except BaseException:
            if reaper is not None:
                reaper.release()
            raise
        if reaper is not None:
            reaper.watch(context.address_info["session_dir"])
    else:
        _require_reachable(address)
        try:
            ray.init(address=address, **common)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else exc.__class__.__name__
            raise ConfigError(f"cannot join the Ray cluster at {address} ({first}); start one with "
                              "`ray start --head` on the head node and pass the address it prints, or leave "
                              "the address out for a local Ray") from exc
    previous = _stop_cleanly_on_sigterm()
    try:
        yield ray
    finally:
        ray.shutdown()
        if reaper is not None:
            reaper.release()
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt


def _stop_cleanly_on_sigterm():
    """SIGTERM stops the command as Ctrl-C does (tasks cancelled, journals and tables written, Ray shut
    down) instead of Ray's own handler, which aborts the process. Returns the handler it replaced."""
    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGTERM, _raise_interrupt)


def _require_reachable(address: str, timeout_s: float = 5.0) -> None:
    """A host:port that nothing answers on is refused at once (Ray itself retries for minutes)."""

    host, _, port = address.rpartition(":")
    if "://" in address or not host or not port.isdigit():
        return  # auto, ray://, a name Ray resolves itself
    try:
        socket.create_connection((host, int(port)), timeout=timeout_s).close()
    except OSError as exc:
        raise ConfigError(f"cannot join the Ray cluster at {address}: nothing answers there "
                          f"({exc.strerror or exc}); start one with `ray start --head` on the head node and pass "
                          "the address it prints, or leave the address out for a local Ray") from exc


def cluster_cpus(ray) -> int:
    return int(ray.cluster_resources().get("CPU", 0))


__all__ = ["LOCAL", "ray_session", "import_ray", "describe", "cluster_cpus", "quiet_ray_environment"]

"""Serving a recording to Rerun's web viewer on an address of our choosing.

Rerun 0.41's Python ``serve_grpc`` and ``serve_web_viewer`` listen on every interface (0.0.0.0)
and take no bind address, so anyone on the lab's network could read the data. The bundled
``rerun`` executable takes ``--bind``: ``view --web`` saves the recording to a temporary .rrd and
serves that file with ``rerun --serve-web --bind ADDR``, on 127.0.0.1 unless told otherwise.
"""

from __future__ import annotations

import importlib.util
import ipaddress
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
import urllib.parse
from dataclasses import dataclass
from pathlib import Path

from hingelab.errors import HingelabError

LOOPBACK = "127.0.0.1"
GRPC_PORT = 9876  # Rerun's defaults
WEB_PORT = 9090
START_TIMEOUT_S = 20.0


class WebServeError(HingelabError):
    """The web viewer could not be served (no ``rerun`` executable, a port in use, a bad address)."""


def is_loopback(address: str) -> bool:
    """True for addresses only this machine reaches (127.0.0.0/8, ::1, localhost)."""
    if address == "localhost":
        return True
    try:
        return ipaddress.ip_address(address).is_loopback
    except ValueError:
        return False


def bind_warning(address: str, grpc_port: int = GRPC_PORT, web_port: int = WEB_PORT) -> str | None:
    """The warning ``--bind`` prints when the recording leaves this machine (None on a loopback address)."""
    if is_loopback(address):
        return None
    return (f"warning: serving on {address}: every machine that can reach this one on ports {grpc_port} (gRPC) "
            f"and {web_port} (web viewer) can read the recording, with no password. Leave --bind out to keep "
            f"it on this machine ({LOOPBACK}).")


def rerun_executable() -> str:
    """The ``rerun`` binary of the rerun-sdk wheel (its ``rerun`` script on PATH is a Python wrapper that
    runs the binary as a child, which a stop would orphan), else ``rerun`` on PATH."""
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.submodule_search_locations:
        binary = Path(list(spec.submodule_search_locations)[0]) / "rerun"
        if binary.exists():
            return str(binary)
    found = shutil.which("rerun")
    if found is None:
        raise WebServeError("no `rerun` executable beside this Python or on PATH; reinstall rerun-sdk "
                            "(`pip install rerun-sdk`), or use --save FILE.rrd")
    return found


@dataclass
class WebServer:
    """A running ``rerun --serve-web`` of one .rrd file; ``stop()`` ends it and removes the file."""

    process: subprocess.Popen
    address: str
    grpc_port: int
    web_port: int
    workdir: tempfile.TemporaryDirectory | None

    @property
    def url(self) -> str:
        """The address to open in a browser (it connects the viewer to the gRPC server)."""
        host = socket.gethostname() if self.address in ("0.0.0.0", "::") else self.address  # all interfaces
        host = f"[{host}]" if ":" in host else host
        grpc = f"rerun+http://{host}:{self.grpc_port}/proxy"
        return f"http://{host}:{self.web_port}/?url=" + urllib.parse.quote(grpc, safe="")

    def wait(self) -> None:
        self.process.wait()

    def stop(self) -> None:
        if self.process.poll() is None:
            try:
                os.killpg(self.process.pid, signal.SIGTERM)  # its own session: any child goes too
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait()
            except ProcessLookupError:  # it ended by itself meanwhile
                self.process.wait()
        if self.workdir is not None:
            self.workdir.cleanup()
            self.workdir = None


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now."""
    with socket.socket() as sock:
        sock.bind((LOOPBACK, 0))
        return sock.getsockname()[1]


def _listening(address: str, port: int) -> bool:
    host = "::1" if address == "::" else ("127.0.0.1" if address == "0.0.0.0" else address)
    try:
        with socket.create_connection((host, port), timeout=0.5):
            return True
    except OSError:
        return False


def serve_rrd(rrd: Path, address: str = LOOPBACK, grpc_port: int = GRPC_PORT, web_port: int = WEB_PORT,
              workdir: tempfile.TemporaryDirectory | None = None) -> WebServer:
    """Serve ``rrd`` with Rerun's web viewer on ``address``; returns once both ports listen.
    ``workdir`` (holding ``rrd``) is removed by ``stop()``."""
    log = open(Path(rrd).with_suffix(".serve.log"), "wb")
    command = [rerun_executable(), "--serve-web", "--bind", address, "--port", str(grpc_port),
               "--web-viewer-port", str(web_port), str(rrd)]
    process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                               start_new_session=True)
    server = WebServer(process, address, grpc_port, web_port, workdir)
    log.close()
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        if server.process.poll() is not None:
            lines = Path(rrd).with_suffix(".serve.log").read_text(errors="replace").strip().splitlines()
            server.stop()
            last = lines[-1] if lines else "no output"
            raise WebServeError(f"`rerun --serve-web --bind {address} --port {grpc_port} --web-viewer-port "
                                f"{web_port}` stopped at start ({last}); is a port in use? Give other ports "
                                "with --port and --web-viewer-port")
        if _listening(address, grpc_port) and _listening(address, web_port):
            return server
        time.sleep(0.1)
    server.stop()
    raise WebServeError(f"Rerun's web viewer did not listen on {address}:{grpc_port} and :{web_port} within "
                        f"{START_TIMEOUT_S:.0f} s")


def serving_workdir() -> tempfile.TemporaryDirectory:
    """A private folder for the recording while it is served (removed by ``WebServer.stop``)."""
    return tempfile.TemporaryDirectory(prefix="hingelab-view-")


__all__ = ["GRPC_PORT", "LOOPBACK", "WEB_PORT", "WebServeError", "WebServer", "bind_warning", "free_port",
           "is_loopback", "rerun_executable", "serve_rrd", "serving_workdir"]

"""``hingelab view --web`` serves on this machine only unless ``--bind`` opens it: the listening
sockets of the server it starts are read from /proc/net/tcp(6)."""

from __future__ import annotations

import socket
import urllib.request
from pathlib import Path

import pytest

from hingelab.viewers import view
from hingelab.viewers.web_server import bind_warning, free_port, is_loopback


def _listening_addresses(port: int) -> set[str]:
    """The local addresses that listen on ``port`` (IPv4 dotted, IPv6 as '::' or hex)."""
    found = set()
    for table, width in (("/proc/net/tcp", 8), ("/proc/net/tcp6", 32)):
        if not Path(table).exists():
            continue
        for line in Path(table).read_text().splitlines()[1:]:
            fields = line.split()
            address, hex_port = fields[1].split(":")
            if fields[3] != "0A" or int(hex_port, 16) != port:  # 0A: LISTEN
                continue
            if width == 8:
                found.add(socket.inet_ntoa(bytes.fromhex(address)[::-1]))
            else:
                found.add("::" if int(address, 16) == 0 else address)
    return found


@pytest.fixture(scope="module")
def episode_file(random_pick_dataset) -> Path:
    return next((random_pick_dataset("web") / "episodes").glob("*.mcap"))


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="reads Linux's socket table")
def test_web_view_listens_on_loopback_only(episode_file):
    port, web_port = free_port(), free_port()
    result, _ = view(episode_file, web=True, port=port, web_port=web_port, progress=False)
    try:
        assert _listening_addresses(port) == {"127.0.0.1"}
        assert _listening_addresses(web_port) == {"127.0.0.1"}
        assert result.url.startswith(f"http://127.0.0.1:{web_port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{port}")
        with urllib.request.urlopen(f"http://127.0.0.1:{web_port}/", timeout=10) as response:
            assert response.status == 200  # the web viewer answers
        served = Path(result.server.workdir.name)
        assert list(served.glob("*.rrd"))
    finally:
        result.server.stop()
    assert result.server.process.poll() is not None and not served.exists()  # stopped, the temporary .rrd gone
    assert _listening_addresses(port) == set()


def test_bind_warns_off_loopback():
    assert is_loopback("127.0.0.1") and is_loopback("localhost") and is_loopback("::1")
    assert not is_loopback("0.0.0.0") and not is_loopback("::") and not is_loopback("192.168.1.7")
    assert bind_warning("127.0.0.1") is None
    warning = bind_warning("0.0.0.0", 9876, 9090)
    assert "every machine" in warning and "9876" in warning and "9090" in warning and "127.0.0.1" in warning

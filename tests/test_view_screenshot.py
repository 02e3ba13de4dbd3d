"""``hingelab view PATH --screenshot FILE.png``: Rerun's web viewer drawn in headless Chromium and saved; no
Chromium, a wrong suffix or clashing flags are one line, before anything is logged."""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

import pytest

from hingelab.cli.main import main
from hingelab.viewers import screenshot


@pytest.fixture(scope="module")
def episode_file(random_pick_dataset) -> Path:
    return next((random_pick_dataset("shot") / "episodes").glob("*.mcap"))


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("hingelab: error: "), err
    return err[0]


def test_without_chromium_the_screenshot_is_one_line_and_nothing_is_served(episode_file, tmp_path, monkeypatch,
                                                                           capsys):
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))  # no chromium on it
    monkeypatch.delenv("HINGELAB_CHROMIUM", raising=False)
    served = []
    monkeypatch.setattr("hingelab.viewers.web_server.serve_rrd", lambda *a, **k: served.append(a))
    out = tmp_path / "shot.png"
    assert main(["view", str(episode_file), "--screenshot", str(out)]) == 1
    line = one_line_error(capsys)
    assert "needs Chromium" in line and "apt-get install chromium" in line
    assert not out.exists() and served == []
    monkeypatch.setenv("HINGELAB_CHROMIUM", str(tmp_path / "no-such-browser"))
    assert main(["view", str(episode_file), "--screenshot", str(out)]) == 1
    assert "HINGELAB_CHROMIUM" in one_line_error(capsys)


@pytest.mark.parametrize("argv, words", [
    (["--screenshot", "shot.jpg"], "must end in .png"),
    (["--screenshot", "shot.png", "--web"], "leave out --save and --web"),
    (["--screenshot", "shot.png", "--screenshot-timeout", "0"], "positive number of seconds"),
])
def test_bad_screenshot_flags_are_one_line(episode_file, tmp_path, capsys, argv, words):
    argv = [a if not a.startswith("shot.") else str(tmp_path / a) for a in argv]
    assert main(["view", str(episode_file), *argv]) == 1
    assert words in one_line_error(capsys)
    assert not list(tmp_path.glob("shot.*"))


def png_size(path: Path) -> tuple[int, int]:
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR"
    return struct.unpack(">II", head[16:24])


@pytest.mark.slow
@pytest.mark.skipif(not any(shutil.which(n) for n in screenshot.CHROMIUM_NAMES),
                    reason="needs Chromium (Debian: apt-get install chromium)")
def test_a_screenshot_is_the_drawn_viewer(episode_file, tmp_path, capsys):
    out = tmp_path / "shots" / "episode.png"
    assert main(["view", str(episode_file), "--screenshot", str(out)]) == 0
    assert png_size(out) == screenshot.WINDOW
    assert out.stat().st_size > 50_000  # the drawn viewer, not its dark empty page (about 8 KB)
    assert "saved to" in capsys.readouterr().out
    assert not list(out.parent.glob("*.partial"))

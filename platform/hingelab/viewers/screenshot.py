"""A PNG of Rerun's web viewer showing a recording, taken in headless Chromium (``hingelab view --screenshot``).

The recording is served on 127.0.0.1 as ``view --web`` serves it (``web_server.serve_rrd``); Chromium opens the
viewer's address with no network of its own (the flags Debian's Chromium needs on a closed machine) and
is driven over the DevTools protocol (a WebSocket): a fixed window size, then a capture every few seconds
until three in a row are identical (the viewer has loaded the recording and drawn it) or the time limit
passes. WebGL runs in software (SwiftShader), so a large recording takes a minute or more to draw.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

from hingelab.errors import HingelabError
from hingelab.viewers.web_server import free_port

WINDOW = (1600, 1000)  # px
FIRST_CAPTURE_S = 15.0  # the viewer's wasm loads before anything is drawn
CAPTURE_EVERY_S = 5.0
SETTLED_AFTER = 3  # identical captures in a row: the view stood still for (SETTLED_AFTER - 1) * CAPTURE_EVERY_S
TIMEOUT_S = 240.0
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
# No network beyond localhost, no first-run work, software WebGL (these machines have no GPU)
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-quic", "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--enable-unsafe-swiftshader",
                  "--use-angle=swiftshader", "--hide-scrollbars", "--mute-audio")


class ScreenshotError(HingelabError):
    """No Chromium, or it did not start or draw in time."""


def chromium_executable() -> str:
    """Chromium's executable (``HINGELAB_CHROMIUM``, else the first of ``CHROMIUM_NAMES`` on PATH)."""
    chosen = os.environ.get("HINGELAB_CHROMIUM")
    if chosen:
        if shutil.which(chosen) is None:
            raise ScreenshotError(f"HINGELAB_CHROMIUM={chosen} is not an executable; give Chromium's path")
        return chosen
    for name in CHROMIUM_NAMES:
        found = shutil.which(name)
        if found:
            return found
    raise ScreenshotError("--screenshot needs Chromium, and none is on PATH (tried " + ", ".join(CHROMIUM_NAMES)
                          + "); install it (Debian: apt-get install chromium) or set HINGELAB_CHROMIUM=PATH")


class _DevTools:
    """One page of a running Chromium, driven over the DevTools protocol."""

    def __init__(self, port: int, deadline: float):
        from websockets.sync.client import connect  # only --screenshot needs it

        while True:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=2) as answer:
                    pages = [t for t in json.load(answer) if t.get("type") == "page"]
                if pages:
                    break
            except OSError:
                pass
            if time.monotonic() > deadline:
                raise ScreenshotError(f"Chromium's DevTools did not answer on port {port}")
            time.sleep(0.2)
        self.socket = connect(pages[0]["webSocketDebuggerUrl"], max_size=None, open_timeout=10)
        self.calls = 0

    def call(self, method: str, timeout_s: float = 120.0, **params) -> dict:
        from websockets.exceptions import ConnectionClosed

        self.calls += 1
        try:
            self.socket.send(json.dumps({"id": self.calls, "method": method, "params": params}))
            while True:  # events and older answers until this call's
                message = json.loads(self.socket.recv(timeout=timeout_s))
                if message.get("id") == self.calls:
                    break
        except ConnectionClosed as exc:
            raise ScreenshotError(f"Chromium closed its DevTools connection during {method} ({exc}); did it "
                                  "crash? Try again, or a smaller --max-episodes") from None
        except TimeoutError:
            raise ScreenshotError(f"Chromium did not answer {method} within {timeout_s:.0f} s (a heavy view drawn "
                                  "in software on a busy machine; raise --screenshot-timeout)") from None
        if "error" in message:
            raise ScreenshotError(f"Chromium refused {method}: {message['error'].get('message')}")
        return message.get("result", {})

    def close(self) -> None:
        self.socket.close()


def capture_page(url: str, out: Path, window: tuple[int, int] = WINDOW, timeout_s: float = TIMEOUT_S) -> dict:
    """Open ``url`` in headless Chromium and write a PNG of it to ``out`` once ``SETTLED_AFTER`` captures in a
    row are the same (or ``timeout_s`` has passed: the last capture, ``settled`` False); returns the capture's
    facts (settled, captures, seconds, bytes)."""
    executable = chromium_executable()
    port = free_port()
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="hingelab-chromium-") as profile:
        browser = subprocess.Popen([executable, *CHROMIUM_FLAGS, f"--user-data-dir={profile}",
                                    f"--window-size={window[0]},{window[1]}", f"--remote-debugging-port={port}",
                                    "about:blank"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            page = _DevTools(port, started + 30.0)
            try:
                page.call("Emulation.setDeviceMetricsOverride", width=window[0], height=window[1],
                          deviceScaleFactor=1, mobile=False)
                page.call("Page.navigate", url=url)
                time.sleep(FIRST_CAPTURE_S)
                previous, same, settled, captures = None, 0, False, 0
                while True:
                    left = max(60.0, timeout_s - (time.monotonic() - started))
                    png = base64.b64decode(page.call("Page.captureScreenshot", timeout_s=left, format="png")["data"])
                    captures += 1
                    same = same + 1 if png == previous else 1
                    if same >= SETTLED_AFTER:
                        settled = True
                        break
                    previous = png
                    if time.monotonic() - started > timeout_s:
                        break
                    time.sleep(CAPTURE_EVERY_S)
            finally:
                page.close()
        finally:
            browser.terminate()
            try:
                browser.wait(timeout=10)
            except subprocess.TimeoutExpired:
                browser.kill()
                browser.wait()
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_name(out.name + ".partial")
    partial.write_bytes(png)
    os.replace(partial, out)
    return {"settled": settled, "captures": captures, "seconds": time.monotonic() - started, "bytes": len(png)}


__all__ = ["ScreenshotError", "capture_page", "chromium_executable"]

"""A real headless Chromium driven over the DevTools protocol, for the page tests.

``--dump-dom`` shows markup only; whether a thumbnail actually decoded (``naturalWidth``) or a new capture appears
without a reload can only be asked of the live page, so the test talks to it: Runtime.evaluate and
Page.captureScreenshot over the DevTools websocket (websocket-client, in the test extra).
"""

from __future__ import annotations

import base64
import itertools
import json
import shutil
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

import pytest

from tests.conftest import stop_process

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-dev-shm-usage", "--window-size=1280,900", "--remote-debugging-port=0"]


def chromium_or_skip() -> str:
    """The browser binary; a one-line skip only where none is installed (.ci/run installs one where it can)."""
    for name in ("/usr/bin/chromium", *CHROMIUM_NAMES):
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("no Chromium here and none could be installed (apt-get install chromium)")


class Page:
    """One Chromium with one tab on ``url``; ``close`` ends the browser and removes its profile."""

    def __init__(self, url: str, *, timeout: float = 60.0, flags: tuple[str, ...] = ()) -> None:
        """``flags``: more Chromium switches (the extension test maps BlueOS's host names to loopback addresses)."""
        import websocket  # websocket-client

        self._profile = tempfile.mkdtemp(prefix="merlion-chromium-")
        self._proc = subprocess.Popen([chromium_or_skip(), *FLAGS, *flags, f"--user-data-dir={self._profile}", url],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        self._ids = itertools.count(1)
        try:
            port = self._devtools_port(timeout)
            targets = self._until(lambda: [t for t in self._json(port, "list") if t.get("type") == "page"],
                                  timeout)
            self._ws = websocket.create_connection(targets[0]["webSocketDebuggerUrl"], timeout=timeout,
                                                   suppress_origin=True)
        except BaseException:
            self.close()
            raise

    def _devtools_port(self, timeout: float) -> int:
        """Chromium writes the port it picked into DevToolsActivePort in its profile."""
        marker = Path(self._profile) / "DevToolsActivePort"
        text = self._until(lambda: marker.is_file() and marker.read_text().split("\n", 1)[0].strip(), timeout)
        if not text:
            raise AssertionError(f"chromium did not open its DevTools port (exit {self._proc.poll()})")
        return int(text)

    @staticmethod
    def _json(port: int, what: str) -> Any:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/{what}", timeout=10) as r:
            return json.load(r)

    @staticmethod
    def _until(probe, timeout: float):
        end = time.monotonic() + timeout
        while True:
            value = probe()
            if value or time.monotonic() > end:
                return value
            time.sleep(0.1)

    def call(self, method: str, _session: str | None = None, **params: Any) -> dict:
        """One DevTools command (to an attached target's ``_session``, e.g. another origin's frame); events that
        arrive meanwhile are skipped."""
        ident = next(self._ids)
        self._ws.send(json.dumps({"id": ident, "method": method, "params": params,
                                  **({"sessionId": _session} if _session else {})}))
        while True:
            reply = json.loads(self._ws.recv())
            if reply.get("id") == ident:
                if "error" in reply:
                    raise AssertionError(f"{method}: {reply['error']}")
                return reply.get("result", {})

    def evaluate(self, expression: str) -> Any:
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        if "exceptionDetails" in result:
            raise AssertionError(f"{expression}: {result['exceptionDetails']}")
        return result["result"].get("value")

    def wait_for(self, expression: str, timeout: float = 30.0) -> Any:
        """Poll a JavaScript expression until it is truthy; returns its value (falsy after ``timeout``)."""
        return self._until(lambda: self.evaluate(expression), timeout)

    def screenshot(self, path: str | Path) -> Path:
        data = self.call("Page.captureScreenshot", format="png", captureBeyondViewport=True)["data"]
        Path(path).write_bytes(base64.b64decode(data))
        return Path(path)

    def close(self) -> None:
        ws = getattr(self, "_ws", None)
        if ws is not None:
            ws.close()
        stop_process(self._proc, 10)
        shutil.rmtree(self._profile, ignore_errors=True)

    def __enter__(self) -> Page:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

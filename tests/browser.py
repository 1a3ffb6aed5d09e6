"""A headless Chromium driven over the DevTools protocol (tests only): load a page and
report what a user's browser would show: images decoded, console errors, exceptions,
every request the page made; evaluate scripts in it and click on it.

WebGL runs in software (SwiftShader through ANGLE: ``--use-angle=swiftshader
--enable-unsafe-swiftshader``), so the report's 3-D view draws without a GPU.
"""

from __future__ import annotations

import base64
import json
import os
import re
import signal
import shutil
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run",
                  "--disable-dev-shm-usage"]


def chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


def screenshot(page: Path, png: Path, size=(1200, 2400)) -> None:
    """Save a screenshot of ``page`` (a local file) to ``png``."""
    with tempfile.TemporaryDirectory(ignore_cleanup_errors=True) as profile:
        subprocess.run([chromium(), *CHROMIUM_FLAGS, f"--user-data-dir={profile}", "--hide-scrollbars",
                        f"--window-size={size[0]},{size[1]}", f"--screenshot={png}", page.resolve().as_uri()],
                       check=True, capture_output=True, timeout=120)


def inspect(page: Path, timeout: float = 60.0) -> dict:
    """Load ``page`` in headless Chromium; return ``{"images": [(src_start, complete,
    naturalWidth)], "errors": [messages], "title": str, "requests": [urls]}``."""
    with Tab(timeout) as tab:
        tab.load(page)
        script = ("JSON.stringify({title: document.title, images: Array.from(document.images).map("
                  "i => [i.src.slice(0, 22), i.complete, i.naturalWidth])})")
        out = json.loads(tab.evaluate(script))
        out["errors"], out["requests"] = tab.errors, tab.requests
        return out


class Tab:
    """One headless Chromium with one page, over the DevTools protocol; a context manager.

    ``errors`` collects console errors, failed assertions, uncaught exceptions and error
    log entries; ``requests`` the URL of every request the page made (the page itself
    included), as the protocol's ``Network.requestWillBeSent`` events report them.
    """

    def __init__(self, timeout: float = 60.0, window=(1200, 900), flags=()):
        self.timeout, self.window, self.flags = timeout, window, list(flags)
        self.errors, self.requests = [], []
        self._ids = iter(range(1, 10**9))

    def __enter__(self) -> "Tab":
        import websocket

        self._profile = tempfile.TemporaryDirectory(ignore_cleanup_errors=True)
        self._proc = subprocess.Popen([chromium(), *CHROMIUM_FLAGS, *self.flags, f"--user-data-dir={self._profile.name}",
                                       f"--window-size={self.window[0]},{self.window[1]}",
                                       "--remote-debugging-port=0", "about:blank"],
                                      stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                                      start_new_session=True)  # its own process group: ended whole below
        try:
            port = _devtools_port(self._proc, self.timeout)
            targets = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10).read())
            ws_url = next(t["webSocketDebuggerUrl"] for t in targets if t["type"] == "page")
            self._ws = websocket.create_connection(ws_url, timeout=self.timeout)
            for domain in ("Runtime", "Log", "Page", "Network"):
                self.send(f"{domain}.enable")
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc) -> None:
        os.killpg(self._proc.pid, signal.SIGKILL)  # the group of the browser started above
        self._proc.wait()
        self._profile.cleanup()

    def send(self, method: str, **params) -> dict:
        """Call a DevTools method; collect the events that arrive meanwhile; its result."""
        msg_id = next(self._ids)
        self._ws.send(json.dumps({"id": msg_id, "method": method, "params": params}))
        while True:
            msg = json.loads(self._ws.recv())
            self._collect(msg)
            if msg.get("id") == msg_id:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})

    def load(self, page: Path) -> None:
        """Navigate to ``page`` (a local file) and wait for its load event."""
        self.send("Page.navigate", url=page.resolve().as_uri())
        t0 = time.monotonic()
        while time.monotonic() - t0 < self.timeout:
            msg = json.loads(self._ws.recv())
            self._collect(msg)
            if msg.get("method") == "Page.loadEventFired":
                return
        raise TimeoutError(f"{page} did not load within {self.timeout} s")

    def evaluate(self, expression: str):
        """The value of a JavaScript expression in the page (JSON-able values)."""
        out = self.send("Runtime.evaluate", expression=expression, returnByValue=True)
        if "exceptionDetails" in out:
            raise RuntimeError(f"{expression[:80]}: {out['exceptionDetails'].get('text')}")
        return out["result"].get("value")

    def click(self, x: float, y: float) -> None:
        """A left click (press and release) at page pixel ``(x, y)``, as a mouse makes it."""
        for kind in ("mouseMoved", "mousePressed", "mouseReleased"):
            self.send("Input.dispatchMouseEvent", type=kind, x=x, y=y, button="left" if kind != "mouseMoved" else "none",
                      clickCount=1 if kind != "mouseMoved" else 0)

    def drag(self, start, end, steps: int = 8) -> None:
        """A left-button drag from ``start`` to ``end`` (page pixels)."""
        self.send("Input.dispatchMouseEvent", type="mousePressed", x=start[0], y=start[1], button="left", clickCount=1)
        for k in range(1, steps + 1):
            x, y = (start[0] + (end[0] - start[0]) * k / steps, start[1] + (end[1] - start[1]) * k / steps)
            self.send("Input.dispatchMouseEvent", type="mouseMoved", x=x, y=y, button="left", buttons=1)
        self.send("Input.dispatchMouseEvent", type="mouseReleased", x=end[0], y=end[1], button="left", clickCount=1)

    def screenshot(self, png: Path, clip: dict | None = None) -> None:
        """Save what the page shows (``clip``: ``{x, y, width, height, scale}`` in page pixels)."""
        params = {"format": "png", "captureBeyondViewport": True} | ({"clip": clip} if clip else {})
        Path(png).write_bytes(base64.b64decode(self.send("Page.captureScreenshot", **params)["data"]))

    def _collect(self, msg: dict) -> None:
        method, params = msg.get("method"), msg.get("params", {})
        if method == "Runtime.exceptionThrown":
            d = params["exceptionDetails"]
            self.errors.append(" ".join(filter(None, (d.get("text"), d.get("exception", {}).get("description")))))
        elif method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
            self.errors.append(" ".join(str(a.get("value", a.get("description"))) for a in params.get("args", [])))
        elif method == "Log.entryAdded" and params["entry"].get("level") == "error":
            self.errors.append(params["entry"].get("text", ""))
        elif method == "Network.requestWillBeSent":
            self.requests.append(params["request"]["url"])


def _devtools_port(proc, timeout: float) -> int:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        line = proc.stderr.readline()
        m = re.search(r"DevTools listening on ws://[^:]+:(\d+)/", line)
        if m:
            return int(m.group(1))
        if not line and proc.poll() is not None:
            break
    raise RuntimeError("chromium did not start its DevTools server")

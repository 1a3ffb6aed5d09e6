"""A headless Chromium driven over the DevTools protocol (tests only): load a page and
report what a user's browser would show: images decoded, console errors, exceptions."""

from __future__ import annotations

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

CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-dev-shm-usage"]


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
    naturalWidth)], "errors": [messages], "title": str}``."""
    import websocket

    with tempfile.TemporaryDirectory(ignore_cleanup_errors=True) as profile:
        proc = subprocess.Popen([chromium(), *CHROMIUM_FLAGS, f"--user-data-dir={profile}",
                                 "--remote-debugging-port=0", "about:blank"],
                                stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                                start_new_session=True)  # its own process group: ended whole below
        try:
            port = _devtools_port(proc, timeout)
            targets = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10).read())
            ws_url = next(t["webSocketDebuggerUrl"] for t in targets if t["type"] == "page")
            ws = websocket.create_connection(ws_url, timeout=timeout)
            return _drive(ws, page, timeout)
        finally:
            os.killpg(proc.pid, signal.SIGKILL)  # the group of the browser started above
            proc.wait()


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


def _drive(ws, page: Path, timeout: float) -> dict:
    counter = iter(range(1, 10**6))
    errors = []

    def send(method, **params):
        msg_id = next(counter)
        ws.send(json.dumps({"id": msg_id, "method": method, "params": params}))
        while True:
            msg = json.loads(ws.recv())
            _collect(msg, errors)
            if msg.get("id") == msg_id:
                return msg.get("result", {})

    for domain in ("Runtime", "Log", "Page"):
        send(f"{domain}.enable")
    send("Page.navigate", url=page.resolve().as_uri())
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:  # until the load event
        msg = json.loads(ws.recv())
        _collect(msg, errors)
        if msg.get("method") == "Page.loadEventFired":
            break
    script = ("JSON.stringify({title: document.title, images: Array.from(document.images).map("
              "i => [i.src.slice(0, 22), i.complete, i.naturalWidth])})")
    value = send("Runtime.evaluate", expression=script, returnByValue=True)["result"]["value"]
    out = json.loads(value)
    out["errors"] = errors
    return out


def _collect(msg: dict, errors: list) -> None:
    method, params = msg.get("method"), msg.get("params", {})
    if method == "Runtime.exceptionThrown":
        errors.append(params["exceptionDetails"].get("text", "exception"))
    elif method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
        errors.append(" ".join(str(a.get("value", a.get("description"))) for a in params.get("args", [])))
    elif method == "Log.entryAdded" and params["entry"].get("level") == "error":
        errors.append(params["entry"].get("text", ""))

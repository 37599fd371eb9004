"""A report's ``index.html`` opened in headless Chromium: which images loaded, how many rows each
table shows, and a full-page screenshot (PNG).

Chromium is driven through its DevTools protocol over a pipe (``--remote-debugging-pipe``: it
reads commands on its file descriptor 3 and answers on 4, one JSON message per NUL-terminated
chunk), so nothing beyond the browser itself is needed. It runs with ``--no-sandbox``, which
Chromium requires when run as root, as in containers and CI.
"""

from __future__ import annotations

import base64
import json
import os
import select
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

CHROMIUMS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
#: Taller pages are cut there: Chromium's screenshots fail beyond about 16 k pixels.
MAX_HEIGHT = 16_000
#: Every image's natural size and every table's heading, body rows and drawn height.
PROBE = """JSON.stringify({
  images: Array.from(document.images).map(i => ({
    src: i.getAttribute('src'), width: i.naturalWidth, height: i.naturalHeight})),
  tables: Array.from(document.querySelectorAll('table')).map(t => {
    let e = t.previousElementSibling;
    while (e && !/^H[1-6]$/.test(e.tagName)) e = e.previousElementSibling;
    return {name: e ? e.textContent : '', rows: t.querySelectorAll('tbody tr').length,
            height: t.getBoundingClientRect().height};
  })})"""
#: Resolves once every image has loaded or failed, or after 20 s.
IMAGES_SETTLED = """Promise.race([new Promise(r => setTimeout(r, 20000)),
  Promise.all(Array.from(document.images).map(i => i.complete ? 0 :
    new Promise(r => { i.addEventListener('load', r); i.addEventListener('error', r); })))])"""


#: Runs argv[3:] with the descriptors argv[1] and argv[2] as its 3 and 4 (copied above 9 first,
#: so that neither overwrites the other when one of them already is 3 or 4).
_AS_FDS_3_AND_4 = """import fcntl, os, sys
high = [fcntl.fcntl(int(fd), fcntl.F_DUPFD, 10) for fd in sys.argv[1:3]]
for fd in sys.argv[1:3]:
    os.close(int(fd))
os.dup2(high[0], 3)
os.dup2(high[1], 4)
for fd in high:
    os.close(fd)
os.execvp(sys.argv[3], sys.argv[3:])"""


def find_chromium() -> str | None:
    """The Chromium (or Chrome) executable on PATH, if any."""
    return next((path for name in CHROMIUMS if (path := shutil.which(name))), None)


@dataclass
class PageCheck:
    """What the browser showed: each image (``src``, natural ``width`` and ``height`` in px),
    each table (the heading above it, its body ``rows``, its drawn ``height``) and the
    screenshot's path and size."""

    images: list[dict[str, Any]] = field(default_factory=list)
    tables: list[dict[str, Any]] = field(default_factory=list)
    screenshot: Path | None = None
    size: tuple[int, int] = (0, 0)

    def problems(self) -> list[str]:
        """One sentence per image that did not load and per table drawn without rows."""
        out = [f"image {i['src']} did not load" for i in self.images if not i["width"] > 0]
        out += [
            f"table '{t['name']}' shows no rows"
            for t in self.tables
            if not (t["rows"] > 0 and t["height"] > 0)
        ]
        return out


class _DevTools:
    """Commands to one Chromium over its debugging pipe; events are kept until asked for."""

    def __init__(self, proc: subprocess.Popen[bytes], send: int, receive: int, timeout: float):
        self.proc, self.send, self.receive, self.timeout = proc, send, receive, timeout
        self.buffer, self.last_id = b"", 0
        self.events: list[dict[str, Any]] = []

    def _next(self, deadline: float) -> dict[str, Any]:
        while b"\0" not in self.buffer:
            left = deadline - time.monotonic()
            ready, _, _ = select.select([self.receive], [], [], max(0.0, left))
            if not ready:
                raise TimeoutError("Chromium did not answer in time")
            chunk = os.read(self.receive, 1 << 20)
            if not chunk:
                raise RuntimeError(f"Chromium closed its pipe (exit code {self.proc.poll()})")
            self.buffer += chunk
        message, _, self.buffer = self.buffer.partition(b"\0")
        return dict(json.loads(message))

    def call(self, method: str, session: str | None = None, **params: Any) -> dict[str, Any]:
        self.last_id += 1
        message: dict[str, Any] = {"id": self.last_id, "method": method, "params": params}
        if session:
            message["sessionId"] = session
        os.write(self.send, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + self.timeout
        while True:
            reply = self._next(deadline)
            if reply.get("id") == self.last_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error'].get('message')}")
                return dict(reply.get("result", {}))
            self.events.append(reply)

    def wait_for(self, event: str) -> None:
        deadline = time.monotonic() + self.timeout
        while not any(e.get("method") == event for e in self.events):
            self.events.append(self._next(deadline))


def check_page(
    index: Path,
    screenshot: Path,
    chromium: str | None = None,
    width: int = 1280,
    timeout: float = 60.0,
) -> PageCheck:
    """Open ``index`` in headless Chromium ``width`` CSS pixels wide, wait for every image,
    read the images and tables, and save a screenshot of the whole page to ``screenshot``."""
    exe = chromium or find_chromium()
    if exe is None:
        raise FileNotFoundError("no Chromium on PATH (Debian: apt-get install chromium)")
    to_browser, from_us = os.pipe()
    to_us, from_browser = os.pipe()
    with tempfile.TemporaryDirectory(prefix="armexp-chromium-") as profile:
        args = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                "--remote-debugging-pipe", f"--user-data-dir={profile}", "--no-first-run",
                "--disable-extensions", "--mute-audio", "about:blank"]  # fmt: skip
        proc = subprocess.Popen(
            [sys.executable, "-c", _AS_FDS_3_AND_4, str(to_browser), str(from_browser), *args],
            pass_fds=(to_browser, from_browser),
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        os.close(to_browser)
        os.close(from_browser)
        tools = _DevTools(proc, from_us, to_us, timeout)
        try:
            return _visit(tools, index.resolve(), screenshot, width)
        finally:
            try:
                tools.call("Browser.close")
            except (RuntimeError, TimeoutError, OSError):
                proc.kill()
            proc.wait(timeout=30)
            os.close(from_us)
            os.close(to_us)


def _visit(tools: _DevTools, index: Path, screenshot: Path, width: int) -> PageCheck:
    target = tools.call("Target.createTarget", url="about:blank")["targetId"]
    session = tools.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
    tools.call("Page.enable", session)
    metrics = {"width": width, "deviceScaleFactor": 1, "mobile": False}
    tools.call("Emulation.setDeviceMetricsOverride", session, height=900, **metrics)
    tools.call("Page.navigate", session, url=index.as_uri())
    tools.wait_for("Page.loadEventFired")
    # Chromium defers images far below the viewport: the viewport grows to the whole page
    # (which grows as images load) before the images are waited for.
    height = 0
    for _ in range(4):
        content = tools.call("Page.getLayoutMetrics", session)["cssContentSize"]
        grown = min(MAX_HEIGHT, int(content["height"] + 0.999))
        if grown == height:
            break
        height = grown
        tools.call("Emulation.setDeviceMetricsOverride", session, height=height, **metrics)
        tools.call("Runtime.evaluate", session, expression=IMAGES_SETTLED, awaitPromise=True)
    probe = tools.call("Runtime.evaluate", session, expression=PROBE, returnByValue=True)
    found = json.loads(probe["result"]["value"])
    shot = tools.call("Page.captureScreenshot", session, format="png", captureBeyondViewport=True)
    screenshot.parent.mkdir(parents=True, exist_ok=True)
    screenshot.write_bytes(base64.b64decode(shot["data"]))
    return PageCheck(found["images"], found["tables"], screenshot, (width, height))

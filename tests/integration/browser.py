"""Headless Chromium for the browser tests (Debian's, `make browser-tools`): one page opened
over Chromium's DevTools pipe and photographed as often as a test needs.

Chromium renders the Rerun web viewer's WebGL with its software rasteriser (SwiftShader), so
no GPU is needed; how long the wasm viewer takes to load, connect and draw depends on the
machine, so tests photograph the page until it shows what they wait for.
"""

from __future__ import annotations

import shutil
import signal
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from hercs.apps.launch.child_process import stop_process

WINDOW = (1280, 800)


def chromium() -> str:
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found is None:
        pytest.skip("no chromium here (`make browser-tools` installs Debian's as root): the "
                    "web viewer is not opened in a browser")
    return found


def stop(proc: subprocess.Popen) -> None:
    stop_process(proc, signal.SIGTERM, grace_s=30)


class Browser:
    """Headless Chromium driven over its DevTools pipe (`--remote-debugging-pipe`: JSON
    messages, NUL-terminated, written to its fd 3 and read from its fd 4), so that one page
    loads once and is photographed as often as needed."""

    def __init__(self, profile: Path) -> None:
        import os

        to_browser_r, self._to_browser = os.pipe()
        self._from_browser, from_browser_w = os.pipe()
        self.log_path = profile.with_suffix(".log")
        self._log = self.log_path.open("wb")
        # bash (dash takes one-digit fds only) hands chromium our pipe ends as its fds 3 and
        # 4, then becomes it
        wiring = f'exec "$0" "$@" 3<&{to_browser_r} 4>&{from_browser_w}'
        self.proc = subprocess.Popen(
            ["/bin/bash", "-c", wiring, chromium(), "--headless=new", "--no-sandbox",
             "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--hide-scrollbars",
             "--remote-debugging-pipe", f"--window-size={WINDOW[0]},{WINDOW[1]}",
             f"--user-data-dir={profile}", "about:blank"],  # its own profile: never two on one
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=self._log,
            pass_fds=(to_browser_r, from_browser_w))
        os.close(to_browser_r)
        os.close(from_browser_w)
        self._buffer = b""
        self._next_id = 0
        self._session: str | None = None

    def call(self, method: str, params: dict | None = None, timeout_s: float = 120.0) -> dict:
        import json
        import os
        import select

        self._next_id += 1
        message: dict = {"id": self._next_id, "method": method, "params": params or {}}
        if self._session is not None:
            message["sessionId"] = self._session
        os.write(self._to_browser, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + timeout_s
        while True:
            while b"\0" in self._buffer:
                raw, _, self._buffer = self._buffer.partition(b"\0")
                reply = json.loads(raw)
                if reply.get("id") == self._next_id:
                    assert "error" not in reply, f"{method}: {reply['error']}"
                    return reply.get("result", {})
            left = deadline - time.monotonic()
            assert left > 0, f"chromium did not answer {method} within {timeout_s} s"
            ready, _, _ = select.select([self._from_browser], [], [], left)
            if ready:
                chunk = os.read(self._from_browser, 1 << 20)
                assert chunk, ("chromium closed its DevTools pipe; the end of its log:\n" +
                               self.log_path.read_text(errors="replace")[-3000:])
                self._buffer += chunk

    def open(self, url: str) -> None:
        target = self.call("Target.createTarget", {"url": url})["targetId"]
        self._session = self.call("Target.attachToTarget",
                                  {"targetId": target, "flatten": True})["sessionId"]

    def screenshot(self) -> np.ndarray:
        import base64
        import io

        from PIL import Image

        # optimizeForSpeed: a faster PNG compression, the same pixels
        data = self.call("Page.captureScreenshot",
                         {"format": "png", "optimizeForSpeed": True})["data"]
        return np.asarray(Image.open(io.BytesIO(base64.b64decode(data))).convert("RGB"))

    def close(self) -> None:
        import os

        for fd in (self._to_browser, self._from_browser):
            os.close(fd)
        stop(self.proc)
        self._log.close()


@dataclass
class Shown:
    """The picture that first showed what a test waited for, and when."""

    image: np.ndarray
    after_s: float  # from asking the running Chromium to open the page to this picture
    shots: int
    shot_s: float  # since the picture before it (or since asking): how finely `after_s` is known


def screenshot_until(url: str, out: Path, done: Callable[[np.ndarray], bool], what: str, *,
                     deadline_s: float, settled: Path | None = None) -> Shown:
    """Open `url` once and photograph it until `done(picture)` (the wasm viewer loads,
    connects and draws in its own time; the page has no event to await); the last picture
    goes to `out` either way. With `settled`, go on photographing until two pictures in a row
    are the same (the viewer has drawn all it was sent) or `deadline_s` passes, and save the
    last one there."""
    from PIL import Image

    browser = Browser(out.with_suffix(".profile"))
    try:
        # the clock starts once Chromium answers, as a user's browser is already running
        # when they open the viewer's page: its own start (1-3 s here) is not the viewer's
        browser.call("Browser.getVersion")
        start = time.monotonic()
        browser.open(url)
        shots, after_s = 0, 0.0
        while True:
            image = browser.screenshot()
            before_s, after_s = after_s, time.monotonic() - start
            shots += 1
            Image.fromarray(image).save(out)
            if done(image):
                print(f"{url}: {what} after {after_s:.1f} s, screenshot {shots}")
                if settled is not None:
                    _settle(browser, image, settled, deadline_s - after_s)
                return Shown(image=image, after_s=after_s, shots=shots,
                             shot_s=after_s - before_s)
            assert after_s < deadline_s, (
                f"{url}: the page never {what} in {shots} screenshots over {after_s:.0f} s "
                f"(the last: std {image.std():.1f}; {out})")
            time.sleep(0.2)  # a picture as often as the page renders one: no event to await
    finally:
        browser.close()


def _settle(browser: Browser, image: np.ndarray, out: Path, left_s: float) -> None:
    from PIL import Image

    deadline = time.monotonic() + left_s
    while time.monotonic() < deadline:
        time.sleep(0.2)
        previous, image = image, browser.screenshot()
        Image.fromarray(image).save(out)
        if np.array_equal(previous, image):
            return
    print(f"the page was still changing when the deadline passed; the last picture: {out}")


def loaded(image: np.ndarray) -> bool:
    """The viewer is up, whatever it shows (its loading page is one dark colour and a line)."""
    return float(image.std()) > 20.0

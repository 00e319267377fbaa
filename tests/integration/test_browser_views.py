"""The web viewer in a real browser: headless Chromium (Debian's, `make browser-tools`) opens
the Rerun web viewer of a real FetchReach run, live while `hercs up --rerun` streams it into a
web-serving Rerun proxy, and offline from `hercs view RUN --web`, takes a screenshot and
checks that the page drew the run: the viewer loaded (not its loading or an error page) and
its 3D view holds goal spheres in the colours of reached (green) or missed (red) goals.

Chromium renders the viewer's WebGL with its software rasteriser (SwiftShader), so no GPU is
needed. The page is opened once over Chromium's DevTools pipe and photographed about once a
second until it shows the run or SCREENSHOT_DEADLINE_S passes: how long the wasm viewer takes
to load, connect and draw depends on the machine.
"""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from hercs.apps.child_process import stop_process
from hercs.apps.rerun_draw import FAILURE_RGBA, SUCCESS_RGBA
from tests.integration.launcher_standins import Launcher
from tests.support import free_tcp_port, rerun_binary, wait_for_port

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[2]
SCREENSHOT_DEADLINE_S = 240.0
RUN_TIMEOUT_S = 300.0
WINDOW = (1280, 800)
MIN_GOAL_PIXELS = 100
"""Goal-coloured pixels the 3D view must show (one goal sphere covers ~100-400)."""
SMALL = ["--set", "training.cycles_per_epoch=2", "--set", "training.eval_episodes=2"]


def _chromium() -> str:
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found is None:
        pytest.skip("no chromium here (`make browser-tools` installs Debian's as root): the "
                    "web viewer is not opened in a browser")
    return found


def _stop(proc: subprocess.Popen[str]) -> None:
    stop_process(proc, signal.SIGTERM, grace_s=30)


SCENE = (slice(int(0.08 * WINDOW[1]), int(0.70 * WINDOW[1])),
         slice(int(0.16 * WINDOW[0]), int(0.52 * WINDOW[0])))
"""Where hercs's blueprint puts the 3D view ("episodes (3D)") in a WINDOW-sized page: left of
the curves, below the top bar, right of the sources panel, away from the viewer's own
notifications (top right) and the curves' legends (green and red dots among them)."""


def _goal_pixels(image: np.ndarray) -> tuple[int, int]:
    """Pixels of the 3D view near the reached and missed goal colours (the spheres are shaded
    and blended, so: the colour's dominant channel well above the other two)."""
    scene = image[SCENE]
    r, g, b = (scene[..., i].astype(int) for i in range(3))
    assert SUCCESS_RGBA[1] > SUCCESS_RGBA[0] and FAILURE_RGBA[0] > FAILURE_RGBA[1]
    green = (g > r + 50) & (g > b + 30)
    red = (r > g + 80) & (r > b + 80)
    return int(green.sum()), int(red.sum())


def _shows_the_run(image: np.ndarray) -> bool:
    """The viewer loaded and its 3D view draws goal spheres (a short run's goals: missed
    ones, and reached ones once it learns)."""
    green, red = _goal_pixels(image)
    return _loaded(image) and green + red >= MIN_GOAL_PIXELS


class _Browser:
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
            ["/bin/bash", "-c", wiring, _chromium(), "--headless=new", "--no-sandbox",
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

        data = self.call("Page.captureScreenshot", {"format": "png"})["data"]
        return np.asarray(Image.open(io.BytesIO(base64.b64decode(data))).convert("RGB"))

    def close(self) -> None:
        import os

        for fd in (self._to_browser, self._from_browser):
            os.close(fd)
        _stop(self.proc)  # type: ignore[arg-type]
        self._log.close()


def _screenshot_until(url: str, out: Path, done: Callable[[np.ndarray], bool],
                      what: str) -> np.ndarray:
    """Open `url` once and photograph it until `done(picture)` (the wasm viewer loads,
    connects and draws in its own time); the last picture goes to `out` either way."""
    from PIL import Image

    browser = _Browser(out.with_suffix(".profile"))
    try:
        browser.open(url)
        deadline = time.monotonic() + SCREENSHOT_DEADLINE_S
        shots = 0
        while True:
            image = browser.screenshot()
            shots += 1
            Image.fromarray(image).save(out)
            if done(image):
                print(f"{url}: {what} by screenshot {shots}; goal pixels (green, red) = "
                      f"{_goal_pixels(image)}")
                return image
            assert time.monotonic() < deadline, (
                f"{url}: the page never {what} in {shots} screenshots (the last: std "
                f"{image.std():.1f}, goal pixels {_goal_pixels(image)}; {out})")
            time.sleep(1.0)  # a picture a second: the page has no event to await
    finally:
        browser.close()


def _loaded(image: np.ndarray) -> bool:
    """The viewer is up, whatever it shows (its loading page is one dark colour and a line)."""
    return float(image.std()) > 20.0


@pytest.fixture(scope="module")
def live_run(tmp_path_factory: pytest.TempPathFactory
             ) -> Iterator[tuple[Path, str, Launcher]]:
    """A real run streamed live into a web-serving Rerun proxy: (its run folder, the URL of
    the web viewer page that shows the stream, the run). The run has 200 epochs, so it is
    still going while the tests look (with 3, it had ended before the browser started, and
    the "live" view showed what the proxy had kept); it is stopped in order at the end."""
    _chromium()
    tmp = tmp_path_factory.mktemp("browser")
    grpc, web = free_tcp_port(), free_tcp_port()
    proxy = subprocess.Popen([rerun_binary(), "--serve-web", "--bind", "127.0.0.1", "--port",
                              str(grpc), "--web-viewer-port", str(web)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    run = None
    try:
        wait_for_port(grpc, 60)
        wait_for_port(web, 60)
        stream = f"rerun+http://127.0.0.1:{grpc}/proxy"
        page = f"http://127.0.0.1:{web}/?url={stream}"
        # the control: the same page before any run streams into it shows no run
        empty = _screenshot_until(page, tmp / "before-the-run.png", _loaded, "loaded")
        assert not _shows_the_run(empty), (
            f"the check passes on an empty viewer: goal pixels {_goal_pixels(empty)}")
        run = Launcher([sys.executable, "-m", "hercs.apps.cli", "up", "--task", "reach",
                        "--method", "her-cs", "--epochs", "200", "--run", "browser",
                        "--run-dir", str(tmp / "runs"), "--listen", "tcp/127.0.0.1:0",
                        "--rerun", stream, "--rerun-every", "1", *SMALL], cwd=tmp)
        run.wait_for_line(r"^epoch 1/200  success ", RUN_TIMEOUT_S)
        yield tmp / "runs" / "browser", page, run
    finally:
        if run is not None:
            _stop(run.proc)  # in order: SIGTERM
        _stop(proxy)  # type: ignore[arg-type]


def test_the_live_web_view_of_a_running_run_draws_its_episodes(
        live_run: tuple[Path, str, Launcher], tmp_path: Path) -> None:
    _, url, run = live_run
    _screenshot_until(url, tmp_path / "live.png", _shows_the_run, "drew the run")
    assert run.proc.poll() is None, "the run was still going: a live view, not a recording"


def test_the_offline_web_view_of_a_run_draws_its_episodes(
        live_run: tuple[Path, str, Launcher], tmp_path: Path) -> None:
    run_dir, _, _ = live_run
    web, grpc = free_tcp_port(), free_tcp_port()
    view = Launcher([sys.executable, "-m", "hercs.apps.cli", "view", str(run_dir),
                     "--episodes", "all", "--web", "--web-port", str(web),
                     "--grpc-port", str(grpc), "--no-browser"], cwd=tmp_path)
    try:
        line = view.wait_for_line(r"serving the web viewer at \S+", 120)
        url = line.split("serving the web viewer at ")[1].split()[0]
        _screenshot_until(url, tmp_path / "offline.png", _shows_the_run, "drew the run")
    finally:
        _stop(view.proc)

"""The web viewer in a real browser (tests/integration/browser.py): headless Chromium opens
the Rerun web viewer of a real FetchReach run, live while `hercs up --rerun` streams it into a
web-serving Rerun proxy, and offline from `hercs view RUN --web`, takes a screenshot and
checks that the page drew the run: the viewer loaded (not its loading or an error page) and
its 3D view holds goal marks in the colours of reached (green) or missed (red) goals.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from hercs.apps.launch.router import free_port
from hercs.apps.views.rerun_draw import FAILURE_RGBA, SUCCESS_RGBA
from tests.integration.browser import WINDOW, chromium, loaded, screenshot_until, stop
from tests.integration.launcher_standins import Launcher
from tests.support import rerun_binary, wait_for_port

pytestmark = pytest.mark.integration

SCREENSHOT_DEADLINE_S = 240.0
RUN_TIMEOUT_S = 300.0
MIN_GOAL_PIXELS = 50
"""Goal-coloured pixels the 3D view must show: about two goal marks (3 ui points, ~28 each)."""
SMALL = ["--set", "training.cycles_per_epoch=2", "--set", "training.eval_episodes=2"]


SCENE = (slice(int(0.08 * WINDOW[1]), int(0.70 * WINDOW[1])),
         slice(int(0.16 * WINDOW[0]), int(0.52 * WINDOW[0])))
"""Where hercs's blueprint puts the 3D view ("episodes (3D)") in a WINDOW-sized page: left of
the curves, below the top bar, away from the viewer's own notifications (top right) and the
curves' legends (green and red dots among them)."""


def _goal_pixels(image: np.ndarray) -> tuple[int, int]:
    """Pixels of the 3D view near the reached and missed goal colours (the marks are shaded
    and blended, so: the colour's dominant channel well above the other two)."""
    scene = image[SCENE]
    r, g, b = (scene[..., i].astype(int) for i in range(3))
    assert SUCCESS_RGBA[1] > SUCCESS_RGBA[0] and FAILURE_RGBA[0] > FAILURE_RGBA[1]
    green = (g > r + 50) & (g > b + 30)
    red = (r > g + 80) & (r > b + 80)
    return int(green.sum()), int(red.sum())


def _shows_the_run(image: np.ndarray) -> bool:
    """The viewer loaded and its 3D view draws goal marks (a short run's goals: missed
    ones, and reached ones once it learns)."""
    green, red = _goal_pixels(image)
    return loaded(image) and green + red >= MIN_GOAL_PIXELS


@pytest.fixture(scope="module")
def live_run(tmp_path_factory: pytest.TempPathFactory
             ) -> Iterator[tuple[Path, str, Launcher]]:
    """A real run streamed live into a web-serving Rerun proxy: (its run folder, the URL of
    the web viewer page that shows the stream, the run). The run has 200 epochs, so it is
    still going while the tests look (with 3, it had ended before the browser started, and
    the "live" view showed what the proxy had kept); it is stopped in order at the end."""
    chromium()
    tmp = tmp_path_factory.mktemp("browser")
    grpc, web = free_port(), free_port()
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
        empty = screenshot_until(page, tmp / "before-the-run.png", loaded, "loaded",
                                 deadline_s=SCREENSHOT_DEADLINE_S).image
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
            stop(run.proc)  # in order: SIGTERM
        stop(proxy)


@pytest.mark.full
def test_the_live_web_view_of_a_running_run_draws_its_episodes(
        live_run: tuple[Path, str, Launcher], tmp_path: Path) -> None:
    _, url, run = live_run
    screenshot_until(url, tmp_path / "live.png", _shows_the_run, "drew the run",
                     deadline_s=SCREENSHOT_DEADLINE_S)
    assert run.proc.poll() is None, "the run was still going: a live view, not a recording"


@pytest.mark.full
def test_the_offline_web_view_of_a_run_draws_its_episodes(
        live_run: tuple[Path, str, Launcher], tmp_path: Path) -> None:
    run_dir, _, _ = live_run
    web, grpc = free_port(), free_port()
    view = Launcher([sys.executable, "-m", "hercs.apps.cli", "view", str(run_dir),
                     "--episodes", "all", "--web", "--web-port", str(web),
                     "--grpc-port", str(grpc), "--no-browser"], cwd=tmp_path)
    try:
        line = view.wait_for_line(r"serving the web viewer at \S+", 120)
        url = line.split("serving the web viewer at ")[1].split()[0]
        screenshot_until(url, tmp_path / "offline.png", _shows_the_run, "drew the run",
                         deadline_s=SCREENSHOT_DEADLINE_S)
    finally:
        stop(view.proc)

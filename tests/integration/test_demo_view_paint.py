"""`hercs view --web` of the committed demo log paints its curves and clusters at once (issue
47): headless Chromium photographs the page until both show, within 10 s or `FLOOR_FACTOR` x
Rerun's own time to paint a one-curve recording (the control, measured in the same test) plus
one picture's time, whichever is longer, so the bound scales with the machine. The
measurements behind it: docs/DESIGN.md §6, "The Rerun recording".
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hercs.apps.launch.router import free_port
from hercs.apps.views.rerun_draw import APP_ID, PALETTE, UNCLUSTERED
from hercs.apps.views.rerun_layout import blueprint
from hercs.rl.task_registry import task_spec
from tests.integration.browser import chromium, screenshot_until, stop
from tests.integration.launcher_standins import Launcher
from tests.support import rerun_binary, wait_for_port

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "docs" / "demo" / "push-her-cs"
PAINT_TARGET_S = 10.0
FLOOR_FACTOR = 2.0
"""The demo's first paint over the one-curve recording's, less one picture: measured 0.7-1.5
(idle and under load). With the curves sent last, as before, there were none after 100 s,
over 10x a one-curve recording idle and over 2.2x at load average 8-15."""
DEADLINE_S = 300.0
SCENE = ((0.08, 0.84), (0.02, 0.58))
"""The 3D view in hercs's layout (side panels collapsed), as fractions of the page's height
and width: the left 3/5 of the page below the top bar and above the play bar."""
CURVES = ((0.12, 0.37), (0.62, 1.0))
"""The "success rate" and "throughput" plots: right of the 3D view, below the viewer's own
notifications (top right; the bare viewer's "failed to load examples" has a red icon)."""
MIN_CURVE_PIXELS = 100
"""Coloured pixels of drawn curves (a series line across a plot is ~500, its legend dot ~50;
the plots without data are grey and white)."""
MIN_CLUSTER_COLOURS = 5
"""Of the demo's k=8 cluster colours, those the 3D view must show (centroids and failed goals;
grey, the palette's eighth, also colours the viewer's text and is not counted)."""


def region(image: np.ndarray, where: tuple[tuple[float, float], tuple[float, float]]
           ) -> np.ndarray:
    (top, bottom), (left, right) = where
    height, width = image.shape[:2]  # the page: WINDOW less the browser's own frame
    return image[int(top * height):int(bottom * height), int(left * width):int(right * width)]


def curves_drawn(image: np.ndarray) -> bool:
    plots = region(image, CURVES).astype(int)
    coloured = (plots.max(-1) - plots.min(-1)) > 60
    return int(coloured.sum()) >= MIN_CURVE_PIXELS


def cluster_colours(image: np.ndarray) -> int:
    """How many cluster colours the 3D view shows: palette colours matched within 25 per
    channel on at least 20 pixels (points are shaded, labels drawn over them)."""
    scene = region(image, SCENE).astype(int)
    off = np.abs(scene[:, :, None, :] - PALETTE[None, None].astype(int)).max(-1)
    counts = (off <= 25).sum(axis=(0, 1))
    greys = {i for i, c in enumerate(PALETTE) if len(set(c.tolist())) == 1}
    assert UNCLUSTERED not in [tuple(c) for c in PALETTE]
    return sum(1 for i, n in enumerate(counts) if i not in greys and n >= 20)


def painted(image: np.ndarray) -> bool:
    return curves_drawn(image) and cluster_colours(image) >= MIN_CLUSTER_COLOURS


def one_curve_paint_s(tmp_path: Path) -> float:
    """The control and the yardstick: a recording of one curve (two points of
    `curves/success_rate`) in hercs's layout, streamed to a Rerun proxy like `hercs view
    --web`'s, photographed until its curve shows. The check must fail on it (it has no
    clusters). Returns how long this browser on this machine took to paint it: Rerun's own
    cost of loading its wasm viewer, connecting and drawing a first recording."""
    import rerun as rr

    grpc, web = free_port(), free_port()
    proxy = subprocess.Popen([rerun_binary(), "--serve-web", "--bind", "127.0.0.1", "--port",
                              str(grpc), "--web-viewer-port", str(web)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_for_port(grpc, 60)
        wait_for_port(web, 60)
        stream = f"rerun+http://127.0.0.1:{grpc}/proxy"
        rec = rr.RecordingStream(APP_ID)
        rec.connect_grpc(stream, default_blueprint=blueprint(task=task_spec("push")))
        for epoch, rate in ((1, 0.05), (2, 0.15)):  # on `episode` too, as `hercs view`'s
            rec.set_time("epoch", sequence=epoch)
            rec.set_time("episode", sequence=200 * epoch - 1)
            rec.log("curves/success_rate", rr.Scalars(rate))
        rec.flush()
        shown = screenshot_until(f"http://127.0.0.1:{web}/?url={stream}",
                                 tmp_path / "one-curve.png", curves_drawn, "drew its curve",
                                 deadline_s=DEADLINE_S)
        rec.disconnect()
    finally:
        stop(proxy)
    assert cluster_colours(shown.image) < MIN_CLUSTER_COLOURS, (
        f"the check passes on a recording without clusters: {cluster_colours(shown.image)} "
        f"cluster colours; {tmp_path / 'one-curve.png'}")
    return shown.after_s


@pytest.mark.full
def test_the_demo_log_paints_its_curves_and_clusters_at_once(tmp_path: Path) -> None:
    chromium()
    floor_s = one_curve_paint_s(tmp_path)
    web, grpc = free_port(), free_port()
    view = Launcher([sys.executable, "-m", "hercs.apps.cli", "view", str(DEMO), "--web",
                     "--web-port", str(web), "--grpc-port", str(grpc), "--no-browser"],
                    cwd=tmp_path)
    try:
        line = view.wait_for_line(r"serving the web viewer at \S+", 120)
        url = line.split("serving the web viewer at ")[1].split()[0]
        shown = screenshot_until(url, tmp_path / "demo.png", painted,
                                 "drew the curves and the clusters", deadline_s=DEADLINE_S,
                                 settled=tmp_path / "demo-settled.png")  # docs/images/'s
    finally:
        stop(view.proc)
    bound_s = max(PAINT_TARGET_S, FLOOR_FACTOR * floor_s + shown.shot_s)
    print(f"demo log painted after {shown.after_s:.1f} s (one curve: {floor_s:.1f} s; bound "
          f"{bound_s:.1f} s, a picture taking {shown.shot_s:.1f} s); picture: "
          f"{tmp_path / 'demo.png'}")
    assert shown.after_s <= bound_s, (
        f"the demo log's curves and clusters took {shown.after_s:.1f} s to paint, over "
        f"{bound_s:.1f} s (a recording of one curve painted in {floor_s:.1f} s, a picture took "
        f"{shown.shot_s:.1f} s)")

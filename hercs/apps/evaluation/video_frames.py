"""Frames of `hercs eval --video` that say what they show: a title frame before each episode
("episode 3 of 20"), and on each of its frames the step at the top and, at the bottom, the
episode's outcome and final distance in a green (success) or red (failure) band.

The outcome is known only when the episode ends, so `AnnotatedEpisodes` holds one episode's
frames (T + 1 = 51 for Fetch, ~140 MB at 1280×720) and writes them then.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cache

import numpy as np
from PIL import Image, ImageDraw, ImageFont

TITLE_S = 1.0
"""How long each episode's title frame stays on screen."""
BAND_SHARE = 18
"""A text band is 1/18 of the frame's height (40 px at 720p), at least `MIN_BAND_PX`."""
MIN_BAND_PX = 30
SUCCESS_RGB = (24, 130, 60)
FAILURE_RGB = (170, 30, 30)
TITLE_RGB = (20, 20, 24)
TOP_RGB = (0, 0, 0)
TEXT_RGB = (255, 255, 255)


@cache
def _font(size: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    return ImageFont.load_default(size=size)


def title_frame(size: tuple[int, int], lines: list[str]) -> np.ndarray:
    """A dark (height, width, 3) uint8 frame with `lines` centred."""
    width, height = size
    image = Image.new("RGB", (width, height), TITLE_RGB)
    draw = ImageDraw.Draw(image)
    size_px = max(12, height // 12)
    while size_px > 12 and max(draw.textlength(line, font=_font(size_px))
                               for line in lines) > 0.92 * width:
        size_px -= 1  # the widest line fits, with a margin
    font = _font(size_px)
    step = int(size_px * 1.6)
    top = height // 2 - step * len(lines) // 2
    for i, line in enumerate(lines):
        draw.text((width // 2, top + i * step), line, fill=TEXT_RGB, font=font, anchor="mt")
    return np.asarray(image)


def band_px(height: int) -> int:
    """The height of each text band on a frame `height` pixels high."""
    return max(MIN_BAND_PX, height // BAND_SHARE)


def annotate(rgb: np.ndarray, top: str, bottom: str, success: bool) -> np.ndarray:
    """`rgb` with a black band of text `top` at its top and a green/red band `bottom` at its
    bottom (the frame's rows under the bands are covered, not shifted)."""
    image = Image.fromarray(np.ascontiguousarray(rgb))
    width, height = image.size
    band = band_px(height)
    draw = ImageDraw.Draw(image)
    font = _font(band * 2 // 3)
    margin = band // 4
    draw.rectangle((0, 0, width, band), fill=TOP_RGB)
    draw.text((margin, band // 2), top, fill=TEXT_RGB, font=font, anchor="lm")
    draw.rectangle((0, height - band, width, height),
                   fill=SUCCESS_RGB if success else FAILURE_RGB)
    draw.text((margin, height - band // 2), bottom, fill=TEXT_RGB, font=font, anchor="lm")
    return np.asarray(image)


def outcome_text(success: bool, final_distance: float) -> str:
    return (f"{'success' if success else 'failure'}  ·  final distance to the goal "
            f"{final_distance:.3f} m")


class AnnotatedEpisodes:
    """A frame sink (`frame(episode, step, rgb)`, `episode_end(episode, success,
    distance)`) that writes, per episode, a title frame held `TITLE_S` and then the
    episode's frames annotated, to `write(rgb)`."""

    def __init__(self, write: Callable[[np.ndarray], None], *, episodes: int, fps: int,
                 size: tuple[int, int]) -> None:
        self._write = write
        self._episodes = episodes
        self._title_frames = max(1, round(TITLE_S * fps))
        self._size = size
        self._held: list[np.ndarray] = []
        self.frames = 0
        """Frames written so far, the title frames included."""

    def frame(self, episode: int, step: int, rgb: np.ndarray) -> None:
        self._held.append(np.array(rgb, copy=True))

    def episode_end(self, episode: int, success: bool, distance: float) -> None:
        title = title_frame(self._size, [f"episode {episode + 1} of {self._episodes}",
                                         outcome_text(success, distance)])
        for _ in range(self._title_frames):
            self._emit(title)
        last = len(self._held) - 1
        bottom = outcome_text(success, distance)
        for step, rgb in enumerate(self._held):
            top = f"episode {episode + 1}/{self._episodes}   step {step}/{last}"
            self._emit(annotate(rgb, top, bottom, success))
        self._held = []

    def _emit(self, rgb: np.ndarray) -> None:
        self._write(rgb)
        self.frames += 1

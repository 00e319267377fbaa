"""hercs/apps/evaluation/video_frames.py: a title frame per episode, the step on every frame and the
outcome band in the outcome's colour, written only once the episode's outcome is known."""

from __future__ import annotations

import numpy as np

from hercs.apps.evaluation.video_frames import (
    FAILURE_RGB,
    SUCCESS_RGB,
    TITLE_RGB,
    AnnotatedEpisodes,
    annotate,
    band_px,
    outcome_text,
    title_frame,
)

SIZE = (480, 360)
BAND_PX = band_px(360)


def _band_colour(rgb: np.ndarray) -> tuple[int, ...]:
    """The most common colour of the bottom band (the text is a minority of its pixels)."""
    band = rgb[-BAND_PX:].reshape(-1, 3)
    colours, counts = np.unique(band, axis=0, return_counts=True)
    return tuple(int(c) for c in colours[counts.argmax()])


def test_the_title_frame_is_dark_with_its_lines_written_inside_the_frame() -> None:
    frame = title_frame(SIZE, ["episode 3 of 20", outcome_text(False, 0.1234)])
    assert frame.shape == (360, 480, 3) and frame.dtype == np.uint8
    text = (frame > 128).all(axis=2)
    assert 0.005 < text.mean() < 0.2  # written, not blank and not flooded
    columns = np.nonzero(text.any(axis=0))[0]
    assert columns.min() > 0 and columns.max() < 479  # the wide line was shrunk to fit
    assert tuple(frame[0, 0]) == TITLE_RGB


def test_annotate_covers_top_and_bottom_bands_and_leaves_the_rest() -> None:
    rgb = np.full((360, 480, 3), 100, np.uint8)
    ok = annotate(rgb, "episode 1/2   step 0/50", outcome_text(True, 0.02), success=True)
    bad = annotate(rgb, "episode 2/2   step 0/50", outcome_text(False, 0.2), success=False)
    assert _band_colour(ok) == SUCCESS_RGB and _band_colour(bad) == FAILURE_RGB
    assert (ok[BAND_PX + 1:-BAND_PX - 1] == 100).all()  # the picture between the bands
    assert (ok[:BAND_PX] != 100).any() and (rgb == 100).all()  # the input is not changed


def test_an_episode_is_written_after_its_title_once_its_outcome_is_known() -> None:
    written: list[np.ndarray] = []
    sink = AnnotatedEpisodes(written.append, episodes=2, fps=25, size=SIZE)
    frames = [np.full((360, 480, 3), v, np.uint8) for v in range(51)]
    for t, rgb in enumerate(frames):
        sink.frame(0, t, rgb)
    assert written == []  # held until the outcome is known
    sink.episode_end(0, True, 0.03)
    for t, rgb in enumerate(frames):
        sink.frame(1, t, rgb)
    sink.episode_end(1, False, 0.2)
    assert sink.frames == len(written) == 2 * (25 + 51)
    titles = [i for i, f in enumerate(written) if tuple(f[0, 0]) == TITLE_RGB]
    assert titles == [*range(0, 25), *range(76, 101)]
    assert _band_colour(written[25]) == SUCCESS_RGB and _band_colour(written[-1]) == FAILURE_RGB
    # the frames keep their order: the middle rows of step t are still the value t
    assert [int(f[180, 240, 0]) for f in written[25:76]] == list(range(51))

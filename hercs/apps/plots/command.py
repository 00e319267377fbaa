"""`hercs plot`: which runs, which series each panel draws (`SeriesChoice`), and the figure
and tables written (drawn by plot_figures.py, tabled by plot_tables.py); what is left out is
said on stderr."""

from __future__ import annotations

import sys
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

from hercs.apps.plots.curves import (
    DEFAULT_BAND,
    REFERENCE_CSV,
    Curve,
    PlotError,
    group,
    load_reference,
    load_run,
    method_rank,
)
from hercs.apps.plots.figures import check_band, plot_fig2, plot_figure
from hercs.apps.plots.series import DEFAULT_CHOICE, SeriesChoice, series_label, series_list
from hercs.apps.plots.tables import fig2_panels, fig2_text, tables


def distinct_run_dirs(run_dirs: Sequence[str | Path]) -> tuple[list[Path], int]:
    """The run folders in the order given, each once (the shell glob `push-her-*` also
    matches `push-her-cs-*`, so a command line can name a folder twice), and how many
    folders were named more than once."""
    counts = Counter(Path(d).resolve() for d in run_dirs)
    seen: set[Path] = set()
    out = []
    for d in run_dirs:
        key = Path(d).resolve()
        if key not in seen:
            seen.add(key)
            out.append(Path(d))
    return out, sum(1 for n in counts.values() if n > 1)


def _left_out_note(where: str, left: list[str], limit: int) -> str:
    return (f"{where}: {len(left)} more series not drawn (at most {limit} a panel by "
            f"default): {series_list(left)}; `--all-series` draws every one, `--series "
            "PATTERN` the ones whose key or label matches (e.g. --series '*lag*')")


def choose_series(ours: dict[str, dict[str, list[Curve]]], reference: bool,
                  choice: SeriesChoice, notes: list[str]) -> dict[str, dict[str, list[Curve]]]:
    """The series each task's panel draws (`SeriesChoice`); with `reference` the authors'
    curve of a method drawn counts against the limit too. A note per panel that leaves some
    out."""
    out = {}
    for task, methods in ours.items():
        def cost(key: str, drawn: list[str]) -> int:
            method = key.split("/")[0]
            return 1 + int(reference and all(k.split("/")[0] != method for k in drawn))

        drawn, left = choice.choose(methods, cost)
        if left and not choice.patterns:
            notes.append(_left_out_note(task, left, choice.limit))
        if drawn:
            out[task] = {k: methods[k] for k in drawn}
    return out


def _check_patterns(ours: dict[str, dict[str, list[Curve]]], choice: SeriesChoice) -> None:
    keys = sorted({k for methods in ours.values() for k in methods}, key=method_rank)
    unmatched = [p for p in choice.patterns
                 if not any(SeriesChoice(patterns=(p,)).matches(k) for k in keys)]
    if unmatched:
        raise PlotError(f"--series {' '.join(unmatched)}: matches no series; the runs given "
                        f"have {', '.join(f'{k} ({series_label(k)})' for k in keys)}")


def run_plot(run_dirs: Sequence[str], output: str, *, reference: bool = False,
             table: str | None = None, reference_csv: str | Path = REFERENCE_CSV,
             xmax: int | None = None, figure: int | None = None,
             band: str = DEFAULT_BAND, choice: SeriesChoice = DEFAULT_CHOICE) -> int:
    """`hercs plot`: the figure at `output`, the tables on stdout (and in `table`);
    `figure=2` draws the paper's Fig. 2 layout (the authors' curves always beside ours).
    A panel draws the series `choice` picks; the tables have every one. What is left out,
    and a folder named twice (read once), are said on stderr."""
    check_band(band)
    folders, repeated = distinct_run_dirs(run_dirs)
    notes: list[str] = []
    if repeated:
        notes.append(f"{repeated} run folder{'s' if repeated != 1 else ''} named more than "
                     "once (overlapping globs?): each read once")
    ours = group((load_run(d) for d in folders), notes)
    _check_patterns(ours, choice)
    if figure == 2:
        authors = group(load_reference(reference_csv))
        panels = fig2_panels(ours, authors, choice)
        notes += [_left_out_note(p.title, p.left, choice.limit) for p in panels
                  if p.left and not choice.patterns]
        for note in notes:
            print(f"hercs plot: {note}", file=sys.stderr)
        return _write_outputs(plot_fig2(ours, authors, output, xmax or None, band,
                                        panels), fig2_text(ours, authors, band, choice), table)
    drawn = choose_series(ours, reference, choice, notes)
    ref = None
    if reference:
        published = group(load_reference(reference_csv))
        missing = sorted(set(ours) - set(published))
        if missing:
            notes.append(f"--reference: the authors published no curves for {', '.join(missing)}"
                         f" (they did for {', '.join(sorted(published))}); drawn without them")
        # the authors' curves of the methods drawn, no others
        ref = {task: {m: cs for m, cs in published[task].items()
                      if any(k.split("/")[0] == m for k in drawn.get(task, {}))}
               for task in ours if task in published}
    for note in notes:
        print(f"hercs plot: {note}", file=sys.stderr)
    return _write_outputs(plot_figure(drawn, output, ref, xmax, band), tables(ours, ref), table)


def _write_outputs(path: Path, text: str, table: str | None) -> int:
    print(text, end="")
    if table:
        Path(table).write_text(text)
        print(f"wrote {table}")
    print(f"wrote {path}")
    return 0

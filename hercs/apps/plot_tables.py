"""The milestone tables of `hercs plot` (`--table`) and docs/results/fig2.md, computed with
hercs/apps/plots.py's rule."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from hercs.apps.plots import (
    CI_LEVEL,
    DEFAULT_BAND,
    WINDOW,
    Curve,
    Milestones,
    VariantOf,
    aggregate,
    method_label,
    method_rank,
    milestones,
)


def _fmt_rate(v: float | None) -> str:
    if v is None or math.isnan(v):
        return "–"
    text = f"{v:.2f}"
    return text[1:] if text.startswith("0") else text


def markdown_table(task: str, rows: Sequence[tuple[str, Milestones]]) -> str:
    """One task's milestone table; `rows` are (label, milestones)."""
    if not rows:
        return ""
    first = rows[0][1]
    th, at = list(first.crossing), list(first.at)
    head = (["method", "seeds", "epochs"] + [f"epoch at {t:g}" for t in th]
            + [f"success at {e}" for e in at] + ["success at end"])
    lines = [f"### {task}", "", "| " + " | ".join(head) + " |",
             "|" + "---|" * len(head)]
    for label, m in rows:
        cells = [label, str(m.n_seeds), str(m.n_epochs)]
        cells += ["–" if m.crossing[t] is None else str(m.crossing[t]) for t in th]
        cells += [_fmt_rate(m.at[e]) for e in at] + [_fmt_rate(m.final)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


TABLE_NOTE = (
    f"Seed mean over the epochs every seed reached, {WINDOW}-epoch trailing moving average. "
    "'epoch at x': first epoch whose average exceeds x, counted from 0 (epochs completed "
    "before it, as in the authors' logs and docs/DESIGN.md §5); 'success at n': the average after "
    "the n-th epoch ('end': the last epoch); '–': never / run too short.\n"
)


def tables(ours: dict[str, dict[str, list[Curve]]],
           reference: dict[str, dict[str, list[Curve]]] | None = None) -> str:
    """Markdown for every task in `ours`, authors' rows beside ours when given."""
    parts = []
    for task, methods in ours.items():
        ref = (reference or {}).get(task, {})
        rows: list[tuple[str, Milestones]] = []
        for method in sorted(set(methods) | set(ref), key=method_rank):
            label = method_label(method)
            if method in methods:
                rows.append((label + (" (ours)" if reference is not None else ""),
                             milestones(aggregate(methods[method]))))
            if method in ref:
                rows.append((label + " (authors)", milestones(aggregate(ref[method]))))
        parts.append(markdown_table(task, rows))
    return "\n".join(parts) + ("\n" + TABLE_NOTE if parts else "")




BAND_CAPTIONS: dict[str, str] = {
    "ci": f"the bootstrap {CI_LEVEL * 100:.0f} % interval of their mean (seeds resampled, "
          "a fixed RNG seed)",
    "minmax": "their min–max",
    "both": f"the bootstrap {CI_LEVEL * 100:.0f} % interval of their mean (seeds resampled, "
            "a fixed RNG seed) and, lighter, their min–max",
}


@dataclass(frozen=True)
class FigureStyle:
    """What a caller adds to `hercs plot`'s plain grouping and labels, for the figures it
    commits: its own variants (`variant_of`), each shown as a note after the label
    (`variant_notes`: variant → words, "HER-CS (lag 7)") and explained in Fig. 2's caption
    (`caption_notes`), and the command that drew it (`drawn_by`, for the caption)."""

    variant_of: VariantOf | None = None
    variant_notes: Mapping[str, str] = field(default_factory=dict)
    caption_notes: tuple[str, ...] = ()
    drawn_by: str = "hercs plot --figure 2"
    not_ours: Mapping[str, str] = field(default_factory=dict)
    """Variants whose runs another code made (a peer's, run here): variant → whose, said
    where a row or legend entry would say "ours"."""

    def whose(self, key: str) -> str:
        """"ours", or whose runs a group key's variant says they are (`not_ours`)."""
        return next((self.not_ours[v] for v in key.split("/")[1:] if v in self.not_ours),
                    "ours")


PLAIN_STYLE = FigureStyle()


FIG2_TASKS: tuple[str, ...] = ("FetchPush", "FetchPickAndPlace", "FetchSlide")
FIG2_ROWS: tuple[tuple[str, str], ...] = (("her", "her-cs"), ("her-ebp", "her-ebp-cs"))
FIG2_EPOCHS = 200


def panel_title(task: str, pair: tuple[str, str]) -> str:
    return f"{task}: {' vs '.join(method_label(m) for m in pair)}"


def in_panel(key: str, pair: tuple[str, str]) -> bool:
    """Whether a Fig. 2 panel of `pair` draws method key `key`: the pair's methods, their
    schedule variants (lockstep) and their runs on v1, not the learner's precision variants
    (bf16)."""
    method, *variants = key.split("/")
    return method in pair and "bf16" not in variants


def has_ours(pair: tuple[str, str], ours: dict[str, list[Curve]]) -> bool:
    """Whether we ran any of the pair's methods (or their variants) on this task."""
    return any(in_panel(key, pair) for key in ours)


def fig2_keys(pair: tuple[str, str], ours: dict[str, list[Curve]],
               ref: dict[str, list[Curve]]) -> list[str]:
    """The method keys of one panel, in the paper's order (`in_panel`)."""
    keys = {k for k in (*ours, *ref) if in_panel(k, pair)}
    return sorted(keys, key=method_rank)


def fig2_text(ours: dict[str, dict[str, list[Curve]]],
              reference: dict[str, dict[str, list[Curve]]], band: str = DEFAULT_BAND,
              style: FigureStyle = PLAIN_STYLE) -> str:
    """docs/results/fig2.md: one milestone table per panel of the paper's Fig. 2 (`band`:
    what the figure's bands are, for its caption; `style`: a caller's variants, their labels
    and caption notes, and the command named as the drawer)."""
    parts = [
        "# Fig. 2: ours beside the authors'", "",
        f"Drawn by `{style.drawn_by}` from the committed runs (docs/results/runs/). Rows "
        "of panels: HER vs HER-CS, HER-EBP vs HER-EBP-CS; columns: FetchPush, "
        "FetchPickAndPlace, FetchSlide. Ours solid (lockstep dash-dotted), the authors' "
        f"dashed; both curves are the {WINDOW}-epoch trailing mean of the seed mean (the paper "
        "smooths over 21 epochs and pads short runs; we do neither), and the bands, over the "
        f"seeds' own {WINDOW}-epoch trailing means, are {BAND_CAPTIONS[band]}. Ours: "
        "gymnasium-robotics Fetch*-v4 on MuJoCo 3, and where labelled (v1) the authors' "
        "environment, gym Fetch*-v1 on mujoco-py, which the authors' curves are on "
        f"(docs/DESIGN.md §9.6){''.join(f'; {note}' for note in style.caption_notes)}.", "",
    ]
    for pair in FIG2_ROWS:
        for task in FIG2_TASKS:
            mine, ref = ours.get(task, {}), reference.get(task, {})
            title = panel_title(task, pair)
            rows: list[tuple[str, Milestones]] = []
            for key in fig2_keys(pair, mine, ref):
                label = method_label(key, style.variant_notes)
                if key in mine:
                    rows.append((f"{label} ({style.whose(key)})",
                                 milestones(aggregate(mine[key]))))
                if key in ref:
                    rows.append((label + " (authors)",
                                 milestones(aggregate(ref[key]))))
            parts.append(markdown_table(title, rows))
            if not has_ours(pair, mine):
                parts += ["No runs of ours yet.", ""]
    return "\n".join(parts) + "\n" + TABLE_NOTE

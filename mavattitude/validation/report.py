"""Tables of validation results: plain text for the terminal, Markdown for ``docs/validation.md``.

The Markdown goes between two marker comments in the document, so the hand-written analysis around
the generated tables survives a re-run.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # only for annotations: runner imports the pipeline
    from mavattitude.validation.runner import Evaluation


BEGIN = "<!-- validate_real: results begin -->"
END = "<!-- validate_real: results end -->"


def rows(evaluations: Sequence[Evaluation]) -> tuple[list[str], list[list[str]]]:
    """Header and cells: one row per path and method, score columns in degrees, coverage, outputs that
    hit the iteration bound, run time."""
    if not evaluations:
        return [], []
    metric = list(evaluations[0].score.columns())
    header = ["path", "method", *metric, "coverage %", "not converged", "time s"]
    body = []
    for ev in evaluations:
        est = ev.estimate
        cells = [est.path, est.method, *(_num(v) for v in ev.score.columns().values())]
        not_converged = est.counters.get("not converged")
        converged_cell = "–" if not_converged is None else str(not_converged)
        body.append([*cells, f"{100 * est.coverage:.1f}", converged_cell, f"{est.elapsed_s:.1f}"])
    return header, body


def _num(value: float) -> str:
    return "–" if math.isnan(value) else f"{value:.2f}"


def text_table(title: str, evaluations: Sequence[Evaluation]) -> str:
    header, body = rows(evaluations)
    widths = [max(len(r[i]) for r in [header, *body]) for i in range(len(header))]
    lines = [title, "  ".join(h.rjust(w) for h, w in zip(header, widths, strict=True))]
    lines += ["  ".join(c.rjust(w) for c, w in zip(r, widths, strict=True)) for r in body]
    return "\n".join(lines)


def markdown_table(evaluations: Sequence[Evaluation]) -> str:
    header, body = rows(evaluations)
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in body]
    return "\n".join(lines)


def write_markdown(document: Path, generated: str) -> None:
    """Replace the generated block of ``document`` (create the document if it does not exist)."""
    block = f"{BEGIN}\n{generated.rstrip()}\n{END}"
    if document.exists():
        text = document.read_text(encoding="utf-8")
        if BEGIN in text and END in text:
            text = text[: text.index(BEGIN)] + block + text[text.index(END) + len(END) :]
        else:
            text = text.rstrip() + "\n\n" + block + "\n"
    else:
        text = f"# Validation on real sensor data\n\n{block}\n"
    document.parent.mkdir(parents=True, exist_ok=True)
    document.write_text(text, encoding="utf-8")

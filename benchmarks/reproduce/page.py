"""The ``reproduction.html`` page: every experiment, published against ours, with a summary table."""

from __future__ import annotations

import html
from pathlib import Path

from benchmarks.report import _STYLE, _png
from benchmarks.reproduce.core import OUTSIDE, WITHIN, Outcome, count_within
from benchmarks.reproduce.output import format_number, plot_rows, summary_line

_VERDICT_STYLE = ".within{background:#f2fbf2}.outside{background:#fdf3f3}td.l{text-align:left}"


def _rows_table(outcome: Outcome) -> str:
    head = "".join(f"<th>{h}</th>" for h in ("row", "published", "ours", "tolerance", "unit", "verdict",
                                                "source", "tolerance / claim", "note"))
    body = []
    for r in outcome.rows:
        why = r.tolerance_note if r.published is not None else r.claim
        cells = [r.key, format_number(r.published), format_number(r.ours), format_number(r.tolerance), r.unit,
                 r.verdict, r.source, why, r.note]
        css = {WITHIN: "within", OUTSIDE: "outside"}.get(r.verdict, "")
        body.append(f'<tr class="{css}">' + "".join(
            f'<td{"" if i in (1, 2, 3) else " class=l"}>{html.escape(str(c))}</td>' for i, c in enumerate(cells))
            + "</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def page(outcomes: list[Outcome], command: str, left_out: list[str] = ()) -> str:
    """The page's HTML.

    Parameters
    ----------
    outcomes : list of Outcome
        The experiments run, in order.
    command : str
        The command line that produced them (shown on the page).
    left_out : list of str
        Registered experiments not run (``--quick``'s heavy ones), named under the summary table so that the
        total is read against them.
    """
    summary = ["<tr><th>experiment</th><th>reproduces</th><th>within</th><th>compared</th><th>run time, s</th></tr>"]
    for o in outcomes:
        within, compared = count_within(o.rows)
        name = html.escape(o.experiment.name)
        summary.append(f'<tr><td class=l><a href="#{name}">{name}</a></td><td class=l>'
                       f"{html.escape(o.experiment.title)}</td><td>{within}</td><td>{compared}</td>"
                       f"<td>{o.seconds:.1f}</td></tr>")
    sections = []
    for o in outcomes:
        e = o.experiment
        parts = [f'<h2 id="{html.escape(e.name)}">{html.escape(e.name)}: {html.escape(e.title)}</h2>',
                 f"<p>{html.escape(e.description)}</p>"]
        if o.error:
            parts.append(f'<p class="goal">failed: {html.escape(o.error)}</p>')
        if o.rows:
            parts.append(f'<img alt="{html.escape(e.name)}" src="data:image/png;base64,{_png(plot_rows(e, o.rows))}">')
            parts.append(_rows_table(o))
        parts += [f'<p><b>{html.escape(key)}</b><br><img alt="{html.escape(e.name)} {html.escape(key)}" '
                  f'src="data:image/png;base64,{data}"></p>' for key, data in o.images.items()]
        if e.findings:
            parts.append(f'<p class="goal"><b>Where ours departs from the source, and why.</b> '
                         f"{html.escape(e.findings)}</p>")
        sections.append("\n".join(parts))
    rows = [r for o in outcomes for r in o.rows]
    missing = (f"<p>Not run here (heavy; <code>tlsbench reproduce NAME</code> runs one): "
               f"{html.escape(', '.join(left_out))}.</p>" if left_out else "")
    return (f"<!doctype html><html><head><meta charset=utf-8><title>Reproduction of the sources</title>"
            f"<style>{_STYLE}{_VERDICT_STYLE}</style></head><body><h1>Reproduction of the published experiments</h1>"
            f"<p><code>{html.escape(command)}</code>: <b>{summary_line(rows)}</b>. A row is within when ours lies "
            f"within the stated tolerance of the published value or, where the source gives only a trend (or keeps "
            f"its numbers back: the ch.2 ROP values and the goniometer slopes), when the trend holds; rows that only "
            f"report ours are not counted.</p><table>{''.join(summary)}</table>{missing}" + "\n".join(sections)
            + "</body></html>")


def write_page(outcomes: list[Outcome], path, command: str, left_out: list[str] = ()) -> Path:
    """Write :func:`page` to ``path``; returns the path.

    Parameters
    ----------
    outcomes : list of Outcome
        The experiments run.
    path : str or Path
        Output file.
    command : str
        The command line shown on the page.
    left_out : list of str
        Registered experiments not run (see :func:`page`).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(page(outcomes, command, left_out))
    return path

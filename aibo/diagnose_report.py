"""Figures and the self-contained HTML page of ``aibo diagnose`` (matplotlib Agg, images embedded)."""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from aibo_core.atomic import atomic_write  # noqa: E402


def _save(fig, path: Path) -> None:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    atomic_write(path, lambda f: f.write(buf.getvalue()))


def signature_panels(path: Path, before: list, after: list, n: int = 6) -> None:
    """The ``n`` strongest residual signatures of the base model, with the same pairs after the refit."""
    top = before[:n]
    after_by = {(s.residual, s.variable): s for s in after}
    cols = 3
    rows = (len(top) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.0 * rows), squeeze=False)
    for ax, s in zip(axes.ravel(), top):
        ax.errorbar(s.centers, s.means, yerr=s.errors, marker="o", color="tab:red", label="base model")
        a = after_by.get((s.residual, s.variable))
        if a is not None:
            ax.errorbar(a.centers, a.means, yerr=a.errors, marker="s", color="tab:blue", label="with named effects")
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.set_xlabel(s.variable)
        ax.set_ylabel(s.residual)
        ax.set_title(f"p = {s.p_value:.1g}", fontsize=9)
    for ax in axes.ravel()[len(top):]:
        ax.axis("off")
    axes.ravel()[0].legend(fontsize=8)
    fig.suptitle("Where the base model and the data disagree (mean residual per bin, +- 1 s.e.)")
    fig.tight_layout()
    _save(fig, path)


def gap_bars(path: Path, before: dict[str, float], after: dict[str, float]) -> None:
    """Held-out gap and innovation consistency before and after adding the named effects."""
    keys = [("gap", "held-out NLL per sighting (nats)"), ("nis_mean", "mean NIS (2 expected)"),
            ("nis_outside", "share outside chi2 95% band (0.05)"), ("whiteness", "lag-1 autocorrelation (0)")]
    fig, axes = plt.subplots(1, len(keys), figsize=(3.2 * len(keys), 3.0))
    for ax, (k, label) in zip(axes, keys):
        ax.bar(["before", "after"], [before[k], after[k]], color=["tab:red", "tab:blue"])
        ax.set_title(label, fontsize=9)
    fig.suptitle("Before and after adding the named effects (held-out half)")
    fig.tight_layout()
    _save(fig, path)


def _img(path: Path) -> str:
    data = base64.b64encode(path.read_bytes()).decode()
    return f'<img src="data:image/png;base64,{data}" style="max-width:100%">'


def html_page(path: Path, report: dict[str, Any], text: str, figures: list[Path]) -> None:
    """One self-contained page: the verdict first, then the figures, the candidates and the full text."""
    verdict = ("Named: " + ", ".join(f"<b>{html.escape(e['name'])}</b> {html.escape(str(e['parameters']))}"
                                    for e in report["effects"])) if report["effects"] else "Named: <b>none</b>"
    rows = "".join(
        f"<tr><td>{c['round']}</td><td>{html.escape(c['name'])}</td><td>{c['gain_train']:.1f}</td>"
        f"<td>{c['gain_heldout']:.1f}</td><td>{c['p_value']:.2g}</td><td>{'yes' if c['significant'] else ''}</td>"
        f"<td>{'' if c['identifiable'] else 'no'}</td><td>{html.escape(c['note'])}</td></tr>"
        for c in report["candidates"])
    body = f"""<!doctype html><html><head><meta charset="utf-8"><title>aibo diagnose</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto}}td,th{{padding:2px 8px;border-bottom:1px solid #ddd}}
pre{{background:#f6f6f6;padding:1em;overflow:auto}}</style></head><body>
<h1>Discrepancy report</h1><p>{verdict}</p>
<p>Gap ({html.escape(report['gap_metric'])}): <b>{report['gap_before']:.4f}</b> before,
<b>{report['gap_after']:.4f}</b> after (lower is better).</p>
{''.join(_img(p) for p in figures)}
<h2>Candidates</h2><table><tr><th>round</th><th>effect</th><th>train gain (nats)</th><th>held-out gain (nats)</th>
<th>p</th><th>significant</th><th>identifiable</th><th>note</th></tr>{rows}</table>
<h2>Full report</h2><pre>{html.escape(text)}</pre></body></html>"""
    atomic_write(path, lambda f: f.write(body.encode()))

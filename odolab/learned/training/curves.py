"""Training curves: rows of numbers per epoch, kept as CSV and drawn as small multiples."""

from __future__ import annotations

import csv
import io
import os
import time
from collections.abc import Sequence
from typing import Any

from odolab.io.atomic import write_bytes_atomic

#: A training redraws its curves' figure after an epoch at most once in this many seconds (drawing
#: takes about a second; its CSV is written after every epoch) and always when it stops.
REDRAW_SECONDS = 60.0


class Curves:
    """Rows (dicts of numbers and labels) accumulated over epochs; saved atomically as CSV."""

    def __init__(self, rows: Sequence[dict[str, Any]] = ()) -> None:
        self.rows: list[dict[str, Any]] = [dict(r) for r in rows]

    def add(self, rows: Sequence[dict[str, Any]]) -> None:
        self.rows.extend(dict(r) for r in rows)

    def to_csv(self, path: str | os.PathLike) -> None:
        """All rows, columns in first-seen order."""
        columns: list[str] = []
        for row in self.rows:
            columns += [k for k in row if k not in columns]
        out = io.StringIO()
        writer = csv.DictWriter(out, columns, lineterminator="\n")
        writer.writeheader()
        for row in self.rows:
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        write_bytes_atomic(path, out.getvalue().encode())

    def plot(
        self,
        path: str | os.PathLike,
        *,
        x: str,
        series: dict[str, dict[str, Any]],
        rows: str,
        cols: str,
        where: dict[str, Any] | None = None,
        ylabel: dict[str, str] | None = None,
        title: str = "",
        scale: dict[str, float] | None = None,
        wrap: int | None = None,
        final: bool = True,
    ) -> None:
        """Small multiples: one panel per (``rows`` value, ``cols`` value), ``x`` on the horizontal axis
        and one line per ``series`` column (value: matplotlib style, with ``label``). ``where``
        filters rows; ``scale`` multiplies values per ``cols`` value (e.g. rad -> deg);
        ``ylabel`` per ``cols`` value; ``wrap``: at most this many panels a line, the panels then
        read in order left to right, top to bottom; ``final=False`` (after an epoch, the training goes
        on): a figure at ``path`` drawn less than :data:`REDRAW_SECONDS` ago is kept."""
        if not final:
            try:
                if time.time() - os.stat(path).st_mtime < REDRAW_SECONDS:
                    return
            except OSError:
                pass  # no figure yet: draw it
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.ticker import MaxNLocator

        data = [r for r in self.rows if all(r.get(k) == v for k, v in (where or {}).items())]
        row_keys = list(dict.fromkeys(r[rows] for r in data))
        col_keys = list(dict.fromkeys(r[cols] for r in data))
        if not data:
            return
        panels = [(rk, ck) for rk in row_keys for ck in col_keys]
        n_cols = min(wrap, len(panels)) if wrap else len(col_keys)
        n_rows = -(-len(panels) // n_cols)
        fig, axes = plt.subplots(
            n_rows, n_cols, figsize=(3.6 * n_cols, 2.6 * n_rows), squeeze=False, constrained_layout=True
        )
        for ax in axes.flat[len(panels) :]:
            ax.set_visible(False)
        for k, (rk, ck) in enumerate(panels):
            ax = axes.flat[k]
            cell = [r for r in data if r[rows] == rk and r[cols] == ck]
            factor = (scale or {}).get(ck, 1.0)
            for column, style in series.items():
                pts = [(r[x], r[column] * factor) for r in cell if r.get(column) not in (None, "")]
                if pts:
                    xs, ys = zip(*pts)
                    ax.plot(xs, ys, **{"marker": "o", "markersize": 3, **style})
            ax.set_title(f"{rk}: {ck}", fontsize=9)
            ax.set_xlabel(x)
            ax.set_ylabel((ylabel or {}).get(ck, ""))
            ax.grid(alpha=0.3)
            values = [r[c] * factor for r in cell for c in series if r.get(c) not in (None, "")]
            ax.set_ylim(0, 1.15 * max(values) if values and max(values) > 0 else 1)
            xs_all = [r[x] for r in cell if r.get(x) not in (None, "")]
            if xs_all and min(xs_all) == max(xs_all):  # one epoch: whole-number ticks around it
                ax.set_xlim(min(xs_all) - 1, max(xs_all) + 1)
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))
            if k == 0:
                ax.legend(fontsize=7)
        if title:
            fig.suptitle(title, fontsize=10)
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=110)
        plt.close(fig)
        write_bytes_atomic(path, buffer.getvalue())

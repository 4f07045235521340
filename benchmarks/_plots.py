"""The one plotting helper of the benchmarks: matplotlib charts (the ``bench`` extra) written as PNG.

Charts are grids of small panels (one per case) sharing a legend: :func:`panels`, then
:func:`line_chart` / :func:`bar_chart` on each axis, then :func:`save`.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import matplotlib

matplotlib.use("Agg")  # files only: no display on the benchmark machines
import matplotlib.pyplot as plt  # noqa: E402


def panels(count: int, cols: int, size: tuple[float, float] = (4.2, 3.0)) -> tuple[Any, list[Any]]:
    """A figure of ``count`` panels in rows of ``cols`` (inches per panel ``size``); unused cells hidden."""
    rows = -(-count // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(size[0] * cols, size[1] * rows), squeeze=False)
    flat = list(axes.ravel())
    for ax in flat[count:]:
        ax.set_visible(False)
    return fig, flat[:count]


def line_chart(ax: Any, title: str, series: dict[str, tuple[Sequence[float], Sequence[float], str]], xlabel: str,
               ylabel: str, vline: float | None = None) -> None:
    """Lines with markers: ``series`` label -> (xs, ys, matplotlib colour); a dashed vertical line at ``vline``."""
    for label, (xs, ys, colour) in series.items():
        ax.plot(xs, ys, marker="o", markersize=3, color=colour, label=label)
    if vline is not None:
        ax.axvline(vline, color="0.45", linestyle="--", linewidth=1)
    ax.axhline(0, color="0.6", linewidth=0.8)
    ax.set(title=title, xlabel=xlabel, ylabel=ylabel)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)


def bar_chart(ax: Any, title: str, groups: Sequence[str], series: dict[str, tuple[Sequence[float], str]],
              ylabel: str = "") -> None:
    """Grouped bars: ``series`` label -> (one value per group, matplotlib colour)."""
    width = 0.8 / len(series)
    for k, (label, (values, colour)) in enumerate(series.items()):
        ax.bar([g + (k - (len(series) - 1) / 2) * width for g in range(len(groups))], values, width, color=colour,
               label=label)
    ax.set_xticks(range(len(groups)), groups)
    ax.axhline(0, color="black", linewidth=0.8)
    ax.set(title=title, ylabel=ylabel)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)


def save(fig: Any, path: Path) -> None:
    """Write ``fig`` as a PNG (tight layout, 100 dpi) and free it."""
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)

"""Charts with matplotlib: one figure style, written as PNG, SVG or PDF.

Figures are made with matplotlib's object API on the Agg canvas (no pyplot, no global
backend, no screen), so drawing is the same in a terminal, a test or a server. Each chart
module (drift history, paths, errors over time, residuals) builds a
:class:`matplotlib.figure.Figure`; :func:`save_figure` writes it atomically in the format
its file name asks for.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

from rigcal.errors import InputError
from rigcal.io.files import atomic_write_bytes

FORMATS = (".png", ".svg", ".pdf")

# Colours shared by every chart (matplotlib's tab10): truth, ok and drifted, methods.
TRUTH = "#1f77b4"
OK = "#2ca02c"
DRIFTED = "#d62728"
METHODS = ("#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#7f7f7f", "#17becf")


def figure(width_in: float = 9.0, height_in: float = 6.0) -> Any:
    """A new figure on the Agg canvas, with rigcal's style."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def style(ax: Any, title: str, xlabel: str, ylabel: str) -> None:
    """Title, axis labels and a light grid; matplotlib picks the ticks."""
    ax.set_title(title, fontsize=11)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, color="#dddddd", linewidth=0.6)
    ax.set_axisbelow(True)


def figure_bytes(fig: Any, fmt: str) -> bytes:
    """The figure encoded as ``fmt`` (".png", ".svg" or ".pdf")."""
    import matplotlib

    buf = io.BytesIO()
    # Fixed metadata and SVG ids, so the same data give the same bytes.
    meta = {".png": {"Software": None}, ".svg": {"Date": None}, ".pdf": {"CreationDate": None}}[fmt]
    with matplotlib.rc_context({"svg.hashsalt": "rigcal"}):
        fig.savefig(buf, format=fmt[1:], metadata=meta)
    return buf.getvalue()


def save_figure(path: str | Path, fig: Any, force: bool = False) -> Path:
    """Write the figure atomically, as PNG, SVG or PDF by the file's suffix.

    Raises:
        InputError: an unknown suffix.
        OutputError: the file exists and ``force`` is False, or it cannot be written.
    """
    check_chart_name(path)
    return atomic_write_bytes(path, figure_bytes(fig, Path(path).suffix.lower()), force=force)


def check_chart_name(path: str | Path) -> None:
    """Refuse a chart file name of an unknown format before any work."""
    if Path(path).suffix.lower() not in FORMATS:
        raise InputError.at(None, "chart file", str(path), f"a name ending in {', '.join(FORMATS)}")

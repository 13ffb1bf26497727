"""PNG charts of the benchmark reports (``bench trade``, and the studies' mappings and scaling)
with matplotlib, the optional ``plot`` extra: its object API and the Agg canvas only (no pyplot
state), written atomically."""

from __future__ import annotations

import os

from deformgl.errors import DeformglError
from deformgl.files import write_atomic

__all__ = ["new_figure", "save_png"]


def new_figure(nrows: int, ncols: int, *, width: float, height: float, what: str):
    """A figure with an ``nrows x ncols`` grid of axes, each ``width x height`` inches.

    Returns:
        (figure, axes) with ``axes[i][j]``.

    Raises:
        DeformglError: matplotlib is not installed (names ``pip install 'deformgl[plot]'``).
    """
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise DeformglError(f"the {what} chart needs matplotlib ({exc}); pip install 'deformgl[plot]'") from None
    fig = Figure(figsize=(width * ncols, height * nrows + 0.8), dpi=110)
    FigureCanvasAgg(fig)
    return fig, fig.subplots(nrows, ncols, squeeze=False)


def save_png(fig, path: str | os.PathLike[str]) -> None:
    """Write the figure as a PNG through a temporary file and a rename."""
    write_atomic(path, lambda stream: fig.savefig(stream, format="png"))

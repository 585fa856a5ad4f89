"""The one figure helper of every report: matplotlib figures drawn with the object API
(`matplotlib.figure.Figure` and the Agg canvas) and returned as PNG bytes.

Building a report never touches pyplot's global state and needs no display.
"""

from __future__ import annotations

import io
from typing import Any


def new_figure(**kwargs: Any):
    """A `matplotlib.figure.Figure` (``figsize=...`` etc.) on an Agg canvas."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(**kwargs)
    FigureCanvasAgg(fig)
    return fig


def png_bytes(fig, dpi: int = 100) -> bytes:
    """The figure as PNG bytes at ``dpi``, cropped to its content (``bbox_inches="tight"``)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    if not isinstance(fig.canvas, FigureCanvasAgg):
        FigureCanvasAgg(fig)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi, bbox_inches="tight")
    return buffer.getvalue()

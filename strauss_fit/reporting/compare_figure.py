"""The figure of ``strauss-fit compare``: one image, one column per model.

The first column is the target; each further column a model's prediction of the same image
and under it its residual (fit − target, the mean over R, G and B, at the pixels whose three
channels are usable; grey: values not used). Every panel is cropped to the sphere's bounding
box (the thumbnails of the capture report, `strauss_fit.reporting.capture_report.light_panels`),
shown at one display exposure, and every residual on one symmetric colour scale.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..capture import CaptureSamples
from ..color import srgb_encode
from ..errors import StraussFitError
from .figures import new_figure, png_bytes


def comparison_figure(
    samples: CaptureSamples,
    predictions: dict[str, np.ndarray],
    image: int = 0,
    *,
    held_out: Sequence[int] = (),
    order: Sequence[str] | None = None,
) -> bytes:
    """The strip for the 0-based ``image`` of ``samples``: the target, then per model of
    ``order`` (default: the keys of ``predictions``, each (L, P, 3) over every image) its
    prediction above its residual. ``held_out``: 0-based images the models did not see
    (the panel says so). PNG bytes."""
    import matplotlib
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    from .capture_report import light_panels

    if not 0 <= image < samples.count:
        raise StraussFitError(f"image {image + 1} does not exist (there are {samples.count}, numbered from 1)")
    names = [m for m in (order or predictions) if m in predictions]
    if not names:
        raise StraussFitError("no model's prediction to show")
    one = samples.select([image])
    held = image in set(held_out)
    panels = {
        name: light_panels([(one, np.asarray(predictions[name])[image : image + 1], [image + 1], held)])
        for name in names
    }
    first = panels[names[0]]
    residuals = np.stack([panels[name].residual[0] for name in names])
    finite = np.abs(residuals[np.isfinite(residuals)])
    limit = max(float(np.percentile(finite, 99.5)) if finite.size else 0.0, 1e-12)
    cmap = matplotlib.colormaps["RdBu_r"]
    norm = Normalize(-limit, limit)
    h, w = first.sphere.shape
    columns = len(names) + 1
    # the layout in inches: panels of about 130 pixels at the figures' 100 dpi
    panel, gap, side, top, between, bottom = 1.3, 0.08, 0.1, 0.75, 0.08, 0.7
    tall = panel * h / w
    width = 2 * side + columns * panel + (columns - 1) * gap
    height = top + 2 * tall + between + bottom
    fig = new_figure(figsize=(width, height))

    def axes_at(row: int, column: int):
        left = side + column * (panel + gap)
        lower = height - top - (row + 1) * tall - row * between
        return fig.add_axes((left / width, lower / height, panel / width, tall / height))

    axes = [[axes_at(row, column) for column in range(columns)] for row in range(2)]
    axes[0][0].imshow(srgb_encode(first.target[0] * first.exposure), interpolation="nearest")
    axes[0][0].set_title("target", fontsize=8)
    axes[1][0].axis("off")
    axes[1][0].text(
        0.5,
        0.5,
        "fit − target\n(mean over R, G, B)",
        ha="center",
        va="center",
        fontsize=7,
        transform=axes[1][0].transAxes,
    )
    for column, name in enumerate(names, 1):
        p = panels[name]
        axes[0][column].imshow(srgb_encode(p.fitted[0] * first.exposure), interpolation="nearest")
        axes[0][column].set_title(f"{name}\nrel. RMS {100 * p.relative_rms[0]:.2f} %", fontsize=8)
        rgba = cmap(norm(np.nan_to_num(p.residual[0])))
        rgba[~p.sphere] = (1.0, 1.0, 1.0, 1.0)
        rgba[p.sphere & ~np.isfinite(p.residual[0])] = (0.72, 0.72, 0.72, 1.0)
        axes[1][column].imshow(rgba, interpolation="nearest")
    for row in axes:
        for ax in row:
            ax.set_xticks([])
            ax.set_yticks([])
    name = Path(samples.files[image]).name.replace("$", r"\$")  # not mathtext
    fig.text(
        0.5,
        1 - 0.08 / height,
        f"image {image + 1}: {name}" + (" (held out: predicted)" if held else ""),
        ha="center",
        va="top",
        fontsize=9,
    )
    cax = fig.add_axes(
        ((side + panel + gap) / width, 0.42 / height, (columns - 1) * (panel + gap) / width - gap / width, 0.1 / height)
    )
    bar = fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), cax=cax, orientation="horizontal")
    bar.ax.tick_params(labelsize=7)
    bar.set_label("fit − target (linear; grey: not used)", fontsize=7)
    return png_bytes(fig)

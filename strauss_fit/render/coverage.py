r"""How much of each pixel's footprint the sphere covers.

The renderer samples each pixel at its centre (``docs/formats.md``): a pixel "shows the
sphere" when the ray through its centre hits it. A camera, or a renderer that integrates
over the pixel's area (Mitsuba's box filter, any anti-aliased image), records along the
silhouette a mix of sphere and background instead. Fitting such *edge pixels* as if they
were sphere pixels sampled at the centre biases the fit: on a noise-free Lambertian sphere
rendered by Mitsuba, the 252 partly covered pixels of a 64 × 64 image pulled smoothness
from 0 to 0.12 (their dimming mimics the darker limb of a smoother material).

:func:`pixel_coverage` gives, per pixel, the fraction of its square footprint that shows
the sphere; :func:`fully_covered` the pixels whose whole footprint does. The projected
sphere is convex in the image plane (a disk for the orthographic camera, the interior of
an ellipse for the perspective one), so a pixel is fully covered exactly when the rays
through its four corners all hit, and uncovered when none of the rays through a fine grid
over it does. Only pixels whose corners disagree are supersampled.

The fit uses only fully covered pixels by default (``FitOptions.edge_pixels``); the
measurement behind that choice is ``benchmarks/silhouette.py`` (see ``docs/fitting.md``).
"""

from __future__ import annotations

import numpy as np

from ..scene.camera import Camera, intersect_unit_sphere, rays_through

#: Sub-samples per pixel side for the coverage of edge pixels (64 rays per pixel).
COVERAGE_SAMPLES = 8


def _hits(camera: Camera, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Whether the rays through image-plane points (x, y) hit the sphere (float64, NumPy)."""
    import jax.numpy as jnp

    from ..precision import float64

    with float64():
        hit = intersect_unit_sphere(rays_through(camera, x, y, jnp.float64)).hit
    return np.asarray(hit)


def _corner_hits(camera: Camera) -> np.ndarray:
    """(height + 1, width + 1): whether the ray through each pixel corner hits."""
    x = np.arange(camera.width + 1) / camera.width * 2 - 1
    y = 1 - np.arange(camera.height + 1) / camera.height * 2
    xx, yy = np.meshgrid(x, y)
    return _hits(camera, xx, yy)


def fully_covered(camera: Camera) -> np.ndarray:
    """(height, width) bool: pixels whose whole footprint shows the sphere (all four
    corner rays hit; exact, since the projected sphere is convex)."""
    corners = _corner_hits(camera)
    return corners[:-1, :-1] & corners[:-1, 1:] & corners[1:, :-1] & corners[1:, 1:]


def pixel_coverage(camera: Camera, samples: int = COVERAGE_SAMPLES) -> np.ndarray:
    """(height, width) float64 in [0, 1]: the fraction of each pixel's footprint that
    shows the sphere. 1 and 0 where the four corner rays agree (1 exactly, by convexity;
    0 up to a sliver thinner than the pixel, which a sphere of at least a pixel's size
    cannot be), otherwise the fraction of ``samples`` × ``samples`` sub-pixel rays that
    hit (stratified at sub-pixel centres: error below 1/``samples``), kept strictly
    between 0 and 1."""
    corners = _corner_hits(camera)
    count = corners[:-1, :-1].astype(int) + corners[:-1, 1:] + corners[1:, :-1] + corners[1:, 1:]
    coverage = (count == 4).astype(np.float64)
    rows, cols = np.nonzero((count > 0) & (count < 4))
    if rows.size:
        offsets = (np.arange(samples) + 0.5) / samples
        sx = (cols[:, None, None] + offsets[None, None, :]) / camera.width * 2 - 1
        sy = 1 - (rows[:, None, None] + offsets[None, :, None]) / camera.height * 2
        sx, sy = np.broadcast_arrays(sx, sy)
        # a pixel whose corners disagree is partly covered, whatever its samples say: keep
        # it strictly inside (0, 1) (the unsampled sliver is below half a sample)
        half_sample = 0.5 / samples**2
        coverage[rows, cols] = np.clip(_hits(camera, sx, sy).mean(axis=(1, 2)), half_sample, 1 - half_sample)
    return coverage

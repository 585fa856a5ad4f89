r"""How much of each pixel's footprint the sphere covers.

The renderer samples each pixel at its centre (``docs/formats.md``): a pixel "shows the
sphere" when the ray through its centre hits it. A camera, or a renderer that integrates
over the pixel's area (Mitsuba's box filter, any anti-aliased image), records along the
silhouette a mix of sphere and background instead. Fitting such *edge pixels* as if they
were sphere pixels sampled at the centre biases the fit: on a noise-free Lambertian sphere
rendered by Mitsuba, the 252 partly covered pixels of a 64 × 64 image pulled smoothness
from 0 to 0.12 (their dimming mimics the darker limb of a smoother material).

`pixel_coverage` gives, per pixel, the fraction of its square footprint that shows
the sphere; `fully_covered` the pixels whose whole footprint does. The projected
sphere is convex in the image plane (a disk for the orthographic camera, the interior of
an ellipse for the perspective one), so a pixel is fully covered exactly when the rays
through its four corners all hit, and uncovered when none of the rays through a fine grid
over it does. Only pixels whose corners disagree are supersampled.

Which pixels a fit uses (``FitOptions.edge_pixels``): by default (``"auto"``) the fit
looks at the silhouette (`silhouette_blend`). Where a pixel's centre misses the sphere
but its footprint does not, a point-sampled image shows pure background and a blended one
(box filter, camera) background mixed with as much of the sphere as covers the pixel; when
the target shows no such mix, the image is point-sampled (strauss-fit's own renders) and
the edge pixels are exact — they are used, since near s = 0, where smoothness
shows mostly at the limb, they carry information (at 1 % noise on 8-bit targets,
recovery misses at s = 0 went from 6 of 15 fits to 2 with them); otherwise, or when the
silhouette cannot be checked (a masked target, a background unlike the scene's), only
fully covered pixels are used. The measurements are ``benchmarks/silhouette.py`` and
``benchmarks/recovery.py`` (see ``docs/fitting.md``).
"""

from __future__ import annotations

import threading

import jax.numpy as jnp
import numpy as np
from jax import Array

from ..engine import Kernel
from ..numerics import high_percentile
from ..scene.camera import Camera, intersect_unit_sphere, rays_through

#: Sub-samples per pixel side for the coverage of edge pixels (64 rays per pixel).
COVERAGE_SAMPLES = 8


def _sphere_hits(camera: Camera, x: Array, y: Array) -> Array:
    return intersect_unit_sphere(rays_through(camera, x, y, jnp.float64)).hit


# One compiled program per shape: run eagerly, the rays and the intersection dispatched
# about 25 small programs per call, each traced and lowered in every new process (0.6 s
# of a single fit's start-up, measured 2026-12-02).
_sphere_hits_kernel = Kernel(_sphere_hits, "sphere_hits")


def _hits(camera: Camera, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Whether the rays through image-plane points (x, y) hit the sphere (float64, NumPy)."""
    from ..precision import float64

    with float64():
        return np.asarray(_sphere_hits_kernel(camera, np.asarray(x, np.float64), np.asarray(y, np.float64)))


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


#: At least this many usable pixels of each kind (outer edge, clear background) for
#: `silhouette_blend` to decide.
SILHOUETTE_MIN_PIXELS = 16
#: The clear background must match the scene's (its median offset, per channel) within
#: this fraction of the sphere's brightness (its 98th percentile) for the check to mean
#: anything.
SILHOUETTE_BACKGROUND_MATCH = 0.02
#: The blend factor's standard error above which the silhouette cannot be told apart
#: (0 and 1 then lie less than about three errors apart).
SILHOUETTE_MAX_ERROR = 0.15


def _neighbour_mean(
    values: np.ndarray, weight: np.ndarray, rows: np.ndarray, cols: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """At the pixels (``rows``, ``cols``): the mean of ``values`` (H, W, 3) over each one's
    eight neighbours where ``weight`` (H, W) holds, (K, 3), and how many there were, (K,).
    Only at the pixels asked for (the silhouette's outer edge: a ring of a few hundred
    pixels), not over the whole image (5 ms of a 256² fit)."""
    height, width = weight.shape
    total, count = np.zeros((rows.size, values.shape[-1])), np.zeros(rows.size)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                r, c = rows + dy, cols + dx
                inside = (r >= 0) & (r < height) & (c >= 0) & (c < width)
                r, c = np.where(inside, r, 0), np.where(inside, c, 0)
                counted = inside & weight[r, c]
                total += np.where(counted[:, None], values[r, c], 0.0)
                count += counted
    return total / np.maximum(count, 1)[:, None], count


def silhouette_blend(
    pixels: np.ndarray, usable: np.ndarray, hit: np.ndarray, coverage: np.ndarray, background: np.ndarray
) -> tuple[bool | None, str]:
    r"""Whether an image blends sphere and background along the silhouette (see the module
    docstring): True (blended), False (point-sampled) or None (cannot tell), and why.

    ``pixels`` (H, W, 3) the target, ``usable`` its usable pixels, ``hit`` where the ray
    through the pixel centre hits the sphere, ``coverage`` `pixel_coverage`,
    ``background`` (H, W, 3) the scene's background radiance at every pixel.

    On the *outer edge* (centre missing the sphere, footprint partly covered, coverage c)
    a blended image records `T = B + c\,(S - B)` and a point-sampled one
    `T = B`, plus noise; S is taken as the mean of the pixel's neighbours whose
    centre hits the sphere. The blend factor k of `T - B = k\,c\,(S - B) + ε` is
    fitted by least squares over the outer edge's values, with the noise's σ from the clear
    background (not covered; 1.4826 × the median absolute deviation of T − B): k ≈ 0 is
    point-sampled, k ≈ 1 (or more: the neighbours are partly covered too) blended, and
    the verdict is k > 1/2 — unless k's standard error exceeds
    `SILHOUETTE_MAX_ERROR` (too little contrast against the noise) or the clear
    background does not match the scene's, when it cannot be told."""
    pixels = np.asarray(pixels, dtype=np.float64)
    difference = pixels - background
    outer = (coverage > 0) & ~hit & usable
    clear = (coverage == 0) & usable
    inside = hit & usable
    rows, cols = np.nonzero(outer)
    neighbours = np.zeros_like(pixels)
    count = np.zeros(outer.shape)
    neighbours[rows, cols], count[rows, cols] = _neighbour_mean(pixels, inside, rows, cols)
    outer &= count > 0
    if outer.sum() < SILHOUETTE_MIN_PIXELS or clear.sum() < SILHOUETTE_MIN_PIXELS:
        return None, "too few usable pixels around the sphere to check its silhouette"
    scale = high_percentile(pixels[inside], 98) if inside.any() else 1.0
    scale = scale if scale > 0 else 1.0
    on_clear = difference[clear]
    # an offset (noise alone has none; its spread goes into σ below)
    offset = np.median(on_clear, axis=0)
    mismatch = float(np.max(np.abs(offset)))
    if mismatch > SILHOUETTE_BACKGROUND_MATCH * scale:
        return None, (
            f"the target's background differs from the scene's (by {mismatch:.3g}, "
            f"{mismatch / scale:.1%} of the sphere's brightness), so its silhouette cannot be checked"
        )
    sigma = 1.4826 * float(np.median(np.abs(on_clear - offset)))
    contrast = (coverage[outer][:, None] * (neighbours[outer] - background[outer])).ravel()
    information = float(np.sum(contrast**2))
    if information <= 0:
        return None, "the sphere's edge looks like the background: its silhouette cannot be checked"
    blend = float(np.sum(contrast * difference[outer].ravel()) / information)
    error = sigma / np.sqrt(information)
    if error > SILHOUETTE_MAX_ERROR:
        return None, (
            f"the silhouette's contrast against the noise is too low to tell (blend factor {blend:.2f} ± {error:.2f})"
        )
    blended = blend > 0.5
    return blended, (
        f"pixels just outside the silhouette show {round(blend, 2) + 0.0:.2f} ± {error:.2f} of the sphere's blend "
        "(0: none, 1: as much as they are covered): "
        + ("the silhouette is blended" if blended else "the image is point-sampled")
    )


#: `pixel_coverage`'s results by camera, the most recent last (at most
#: `_COVERAGE_KEPT`): a property of the camera alone, which every target fitted with it
#: shares (2 ms at 256², a fifth of a warm fit's Python before its solve).
_COVERAGE: dict[tuple, np.ndarray] = {}
_COVERAGE_KEPT = 8
_COVERAGE_LOCK = threading.Lock()  # fits may run in several threads


def pixel_coverage(camera: Camera, samples: int = COVERAGE_SAMPLES) -> np.ndarray:
    """(height, width) float64 in [0, 1], read-only: the fraction of each pixel's footprint
    that shows the sphere. 1 and 0 where the four corner rays agree (1 exactly, by
    convexity; 0 up to a sliver thinner than the pixel, which a sphere of at least a
    pixel's size cannot be), otherwise the fraction of ``samples`` × ``samples`` sub-pixel
    rays that hit (stratified at sub-pixel centres: error below 1/``samples``), kept
    strictly between 0 and 1. Computed once per camera (by value) and kept."""
    key = (
        camera.projection,
        camera.width,
        camera.height,
        samples,
        *(np.asarray(v, dtype=np.float64).tobytes() for v in (camera.position, camera.look_at, camera.up)),
        float(camera.fov_deg),
    )
    with _COVERAGE_LOCK:
        coverage = _COVERAGE.pop(key, None)
        if coverage is None:
            coverage = _pixel_coverage(camera, samples)
            coverage.setflags(write=False)  # shared by every caller
            while len(_COVERAGE) >= _COVERAGE_KEPT:
                _COVERAGE.pop(next(iter(_COVERAGE)))
        _COVERAGE[key] = coverage  # the most recent last
        return coverage


def _pixel_coverage(camera: Camera, samples: int) -> np.ndarray:
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

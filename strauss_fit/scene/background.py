r"""What rays that miss the sphere see.

Three kinds, all emitting (unlit) linear radiance:

- ``"color"``: a constant colour.
- ``"checkerboard"``: an infinite plane through ``point`` with normal ``normal``, squares of
  side ``square_size`` alternating ``colors[0]`` and ``colors[1]``; rays that miss the plane
  see ``color``. Square edges are softened,
  `w = \tfrac12 + \tfrac12\tanh(k \sin(\pi u/a)\sin(\pi v/a))` with sharpness
  `k` = ``sharpness``, so that an image seen through a refracting sphere is
  differentiable in the index of refraction (a hard-edged board has zero gradient
  almost everywhere). Towards the horizon the pattern fades to its mean,
  `w = \tfrac12 + \tfrac12 c \tanh(\dots)` with
  `c = \exp(-(f/f_0)^8)`, `f = h / (a \cos^2)` the squares per radian of
  ray direction seen from the origin (h its distance to the plane, cos the ray's with the
  normal) and `f_0` = `HORIZON_FADE`: there a pixel covers many squares,
  and without the fade the radiance's derivative grows without bound (a fit of n once
  followed such rays to n = 1.02 against a true 1.7).
- ``"environment"``: a latitude–longitude image (rows: polar angle from +y at the top to
  −y at the bottom; columns: azimuth, the centre column looking toward −z, increasing
  toward +x), bilinearly interpolated.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..numerics import device_array, dot, safe_arccos, safe_divide, safe_normalize
from ..precision import uses_float64
from .camera import Rays

BACKGROUND_KINDS = ("color", "checkerboard", "environment")


class Background(eqx.Module):
    """A background; see the module docstring for the kinds and their fields."""

    kind: str = eqx.field(static=True, default="color")
    color: Array = eqx.field(default_factory=uses_float64(lambda: device_array(np.zeros(3))))
    point: Array = eqx.field(default_factory=uses_float64(lambda: device_array([0.0, 0.0, -2.0])))
    normal: Array = eqx.field(default_factory=uses_float64(lambda: device_array([0.0, 0.0, 1.0])))
    square_size: Array = eqx.field(default_factory=uses_float64(lambda: device_array(0.5)))
    colors: Array = eqx.field(default_factory=uses_float64(lambda: device_array([[0.9, 0.9, 0.9], [0.1, 0.1, 0.1]])))
    sharpness: Array = eqx.field(default_factory=uses_float64(lambda: device_array(20.0)))
    image: Array | None = None


def _plane_axes(normal: Array) -> tuple[Array, Array]:
    """Two unit vectors spanning the plane with the given normal."""
    helper = jnp.where(jnp.abs(normal[1]) < 0.9, jnp.array([0.0, 1.0, 0.0]), jnp.array([1.0, 0.0, 0.0]))
    u_axis = safe_normalize(jnp.cross(helper.astype(normal.dtype), normal))
    v_axis = jnp.cross(normal, u_axis)
    return u_axis, v_axis


#: Squares per radian of ray direction beyond which the checkerboard fades to its mean
#: colour (the contrast is e^-1 there and e^-256 at twice it).
HORIZON_FADE = 100.0


def _checkerboard(background: Background, rays: Rays) -> Array:
    dtype = rays.direction.dtype
    normal = safe_normalize(background.normal.astype(dtype))
    point = background.point.astype(dtype)
    facing = dot(rays.direction, normal)
    distance = safe_divide(dot(point - rays.origin, normal), facing)
    hits = (facing != 0) & (distance > 0)
    where = rays.origin + distance[..., None] * rays.direction
    u_axis, v_axis = _plane_axes(normal)
    size = background.square_size.astype(dtype)
    u = dot(where - point, u_axis) / size
    v = dot(where - point, v_axis) / size
    # Towards the horizon the squares shrink without bound: seen from the sphere (the
    # origin, at height h above the plane) they pass at f = h / (size cos^2) per radian of
    # ray direction. Fade the pattern to its mean there, as a pixel's footprint would, so
    # that radiance and its derivatives stay bounded. f is measured from the origin, not
    # from each ray's own start, so that a ray's radiance depends on its line only (an
    # n = 1 sphere leaves the board exactly in place). Below a tenth of HORIZON_FADE the
    # contrast is 1 to better than 1e-8. Computed as q = 1/f, floored at 1/3 (contrast
    # e^-6561 = 0), so that nothing overflows and the gradient is finite in float32.
    height = jnp.abs(dot(point, normal))
    # (a plane through the origin has no horizon seen from it: no fade, q = inf)
    inverse_rate = safe_divide(size * facing**2 * HORIZON_FADE, height, fallback=jnp.inf)
    contrast = jnp.exp(-((1.0 / jnp.maximum(inverse_rate, 1.0 / 3.0)) ** 8))
    weight = 0.5 + 0.5 * contrast * jnp.tanh(background.sharpness * jnp.sin(jnp.pi * u) * jnp.sin(jnp.pi * v))
    colors = background.colors.astype(dtype)
    board = colors[1] + weight[..., None] * (colors[0] - colors[1])
    return jnp.where(hits[..., None], board, background.color.astype(dtype))


def _environment(background: Background, rays: Rays) -> Array:
    dtype = rays.direction.dtype
    image = background.image.astype(dtype)
    height, width = image.shape[0], image.shape[1]
    d = safe_normalize(rays.direction)
    azimuth_ok = (d[..., 0] != 0) | (d[..., 2] != 0)
    azimuth = jnp.arctan2(jnp.where(azimuth_ok, d[..., 0], 0.0), jnp.where(azimuth_ok, -d[..., 2], 1.0))
    u = (azimuth / (2 * jnp.pi) + 0.5) * width - 0.5
    v = safe_arccos(d[..., 1]) / jnp.pi * height - 0.5
    v = jnp.clip(v, 0.0, height - 1.0)
    u0 = jnp.floor(u)
    v0 = jnp.clip(jnp.floor(v), 0, max(height - 2, 0))
    fu, fv = u - u0, v - v0
    iu0 = u0.astype(jnp.int32) % width
    iu1 = (iu0 + 1) % width
    iv0 = v0.astype(jnp.int32)
    iv1 = jnp.minimum(iv0 + 1, height - 1)
    top = image[iv0, iu0] * (1 - fu[..., None]) + image[iv0, iu1] * fu[..., None]
    bottom = image[iv1, iu0] * (1 - fu[..., None]) + image[iv1, iu1] * fu[..., None]
    return top * (1 - fv[..., None]) + bottom * fv[..., None]


def background_radiance(background: Background, rays: Rays) -> Array:
    """Radiance (..., 3) seen along ``rays`` that miss the sphere."""
    if background.kind == "color":
        return jnp.broadcast_to(background.color.astype(rays.direction.dtype), rays.direction.shape)
    if background.kind == "checkerboard":
        return _checkerboard(background, rays)
    if background.kind == "environment":
        return _environment(background, rays)
    raise ValueError(f"unknown background kind {background.kind!r}")

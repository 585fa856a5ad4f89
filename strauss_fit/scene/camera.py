"""Cameras and primary rays against the canonical unit sphere at the origin.

Orthographic (see docs/model.md, "Cameras and pixels"): the camera looks down −z from +z, so
V = (0, 0, 1) everywhere; the image spans x, y ∈ [−1, 1] at pixel centres, pixel (row i,
column k) at x = (k + 0.5)/width·2 − 1, y = 1 − (i + 0.5)/height·2, and a pixel shows the
sphere where x² + y² < 1.

Perspective: a pinhole at ``position`` looking at ``look_at`` with vertical field of view
``fov_deg`` and the given ``up`` direction; pixel centres follow the same convention over
[−aspect·tan(fov/2), aspect·tan(fov/2)] × [−tan(fov/2), tan(fov/2)].
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..numerics import device_array, dot, safe_normalize, safe_sqrt
from ..precision import uses_float64

#: Height of the orthographic rays' origin plane above the sphere (any value > 1 works).
ORTHOGRAPHIC_ORIGIN_Z = 2.0


class Camera(eqx.Module):
    """A camera; ``projection`` is ``"orthographic"`` or ``"perspective"``."""

    projection: str = eqx.field(static=True)
    width: int = eqx.field(static=True)
    height: int = eqx.field(static=True)
    position: Array = eqx.field(default_factory=uses_float64(lambda: device_array([0.0, 0.0, 4.0])))
    look_at: Array = eqx.field(default_factory=uses_float64(lambda: device_array(np.zeros(3))))
    up: Array = eqx.field(default_factory=uses_float64(lambda: device_array([0.0, 1.0, 0.0])))
    fov_deg: Array = eqx.field(default_factory=uses_float64(lambda: device_array(30.0)))

    def resized(self, width: int, height: int) -> Camera:
        """The same camera with another image size."""
        return Camera(self.projection, int(width), int(height), self.position, self.look_at, self.up, self.fov_deg)


class Rays(NamedTuple):
    """Rays of shape ``(..., 3)``: ``origin`` and unit ``direction``."""

    origin: Array
    direction: Array


def pixel_centres(width: int, height: int, dtype) -> tuple[Array, Array]:
    """Image-plane coordinates (x, y) ∈ [−1, 1]² of every pixel centre, each (height, width)."""
    x = (np.arange(width) + 0.5) / width * 2 - 1
    y = 1 - (np.arange(height) + 0.5) / height * 2
    xx, yy = np.meshgrid(x, y)
    return jnp.asarray(xx, dtype=dtype), jnp.asarray(yy, dtype=dtype)


def primary_rays(camera: Camera, dtype) -> Rays:
    """One ray per pixel through its centre, shape (height, width, 3)."""
    x, y = pixel_centres(camera.width, camera.height, dtype)
    return rays_through(camera, x, y, dtype)


def rays_through(camera: Camera, x: Array, y: Array, dtype) -> Rays:
    """Rays through image-plane points (x, y) ∈ [−1, 1]² (any matching shapes; pixel
    centres, or points inside a pixel's footprint as for coverage), shape (..., 3)."""
    x, y = jnp.asarray(x, dtype=dtype), jnp.asarray(y, dtype=dtype)
    if camera.projection == "orthographic":
        origin = jnp.stack([x, y, jnp.full_like(x, ORTHOGRAPHIC_ORIGIN_Z)], axis=-1)
        direction = jnp.broadcast_to(jnp.asarray([0.0, 0.0, -1.0], dtype=dtype), origin.shape)
        return Rays(origin, direction)
    position = jnp.asarray(camera.position, dtype=dtype)
    forward = safe_normalize(jnp.asarray(camera.look_at, dtype=dtype) - position)
    right = safe_normalize(jnp.cross(forward, jnp.asarray(camera.up, dtype=dtype)))
    up = jnp.cross(right, forward)
    half = jnp.tan(jnp.deg2rad(jnp.asarray(camera.fov_deg, dtype=dtype)) / 2)
    aspect = camera.width / camera.height
    direction = forward + (x * half * aspect)[..., None] * right + (y * half)[..., None] * up
    direction = safe_normalize(direction)
    return Rays(jnp.broadcast_to(position, direction.shape), direction)


class SphereHit(NamedTuple):
    """Where rays meet the unit sphere: ``hit`` (bool), ``distance`` along the ray,
    ``point`` (= outward normal for the unit sphere)."""

    hit: Array
    distance: Array
    point: Array


def intersect_unit_sphere(rays: Rays, from_inside: bool = False) -> SphereHit:
    """First intersection with the unit sphere at the origin.

    From outside, the near root of |o + τd|² = 1 with τ > 0; ``from_inside`` takes the far
    root (the exit point of a ray travelling inside). Missed rays get distance 0 and point 0.
    """
    b = dot(rays.origin, rays.direction)
    c = dot(rays.origin, rays.origin) - 1
    discriminant = b * b - c
    root = safe_sqrt(discriminant)
    distance = -b + root if from_inside else -b - root
    hit = (discriminant > 0) & (distance > 0)
    distance = jnp.where(hit, distance, 0.0)
    point = rays.origin + distance[..., None] * rays.direction
    point = jnp.where(hit[..., None], safe_normalize(point), 0.0)
    return SphereHit(hit, distance, point)

r"""Rendering the sphere with the Phong model (`strauss_fit.models.phong`).

Phong has no global model: `render_phong` evaluates the local model at every pixel
that sees the sphere and shows the scene's background elsewhere (``scene.depth`` is
ignored; the scene's Strauss ``[material]`` is not used). The ambient term is
`k_a I_a C_d`.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax.numpy as jnp
from jax import Array

from ..models.phong import PhongMaterial, coefficient, phong_shade
from ..precision import uses_float64
from ..scene.background import background_radiance
from ..scene.camera import intersect_unit_sphere, primary_rays
from ..scene.lights import sample_lights
from ..scene.loading import Scene


@eqx.filter_jit
def _render_phong(scene: Scene, material: PhongMaterial, dtype: Any) -> tuple[Array, Array]:
    rays = primary_rays(scene.camera, dtype)
    hits = intersect_unit_sphere(rays)
    normal = hits.point
    to_eye = -rays.direction
    radiance = jnp.zeros(normal.shape, dtype=dtype)
    samples = sample_lights(scene.lights, hits.point)
    if samples is not None:
        per_light = phong_shade(
            material, normal[..., None, :], samples.to_light, to_eye[..., None, :], samples.color
        )  # (H, W, K, 3)
        radiance = radiance + jnp.sum(per_light * samples.irradiance[..., None], axis=-2)
    if scene.lights.ambient is not None:
        radiance = radiance + scene.lights.ambient * coefficient(material.ka) * material.diffuse_color
    miss = background_radiance(scene.background, rays)
    return jnp.where(hits.hit[..., None], radiance, miss), hits.hit


@uses_float64
def render_phong(scene: Scene, material: PhongMaterial, dtype: Any = None) -> tuple[Array, Array]:
    """Render the sphere of ``scene`` with a Phong ``material``: a linear RGB image
    (height, width, 3) and the sphere mask (height, width).

    Local model only (Phong has no global model): pixels that miss the sphere show the
    background. ``dtype`` (``jnp.float32`` or ``jnp.float64``; default float64) sets the
    precision. Differentiable in the material and in the light intensities.
    """
    dtype = jnp.dtype(dtype or jnp.float64)
    return _render_phong(scene.astype(dtype), material.astype(dtype), dtype)

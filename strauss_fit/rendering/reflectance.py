r"""Rendering the sphere with any registered reflectance model
(`strauss_fit.models.reflectance`).

Like Phong's renderer (`strauss_fit.rendering.phong`), the other models are local and
opaque: `render_model` evaluates the model at every pixel that sees the sphere, every
directional and point light as seen from the point, plus the scene's ambient light
reflected as the model's ambient reflectance, and shows the scene's background elsewhere
(``scene.depth`` is ignored; the scene's Strauss ``[material]`` is not used). Radiance per
light: `I\,C_L\,\text{radiance}(x)`, the models' convention (a Lambertian surface of
albedo ρ shows ρ cos α I).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..models.reflectance import ReflectanceModel, reflectance_model
from ..precision import uses_float64
from ..scene.background import background_radiance
from ..scene.camera import intersect_unit_sphere, primary_rays
from ..scene.lights import sample_lights
from ..scene.loading import Scene


@uses_float64
def render_model(scene: Scene, model: str, values: Mapping[str, Any] | None = None) -> tuple[Array, Array]:
    """Render the sphere of ``scene`` with the registered reflectance ``model`` and its
    parameter ``values`` (a mapping as `from_dict`
    reads it; missing ones take the model's defaults): a linear RGB image (height, width, 3)
    and the sphere mask (height, width), float64."""
    reflectance = reflectance_model(model)
    given = dict(values or {})
    defaults = {p.name: np.asarray(p.default_value()).tolist() for p in reflectance.parameters}
    x = reflectance.from_dict({**defaults, **given})
    return _render_local(scene, reflectance, x)


@eqx.filter_jit
def _render_local(scene: Scene, reflectance: ReflectanceModel, x: dict[str, Array]) -> tuple[Array, Array]:
    """The compiled core of `render_model` (the model is a field-less module, so each
    model and image size compiles once; a whole render is one call, as Strauss's is)."""
    dtype = jnp.float64
    rays = primary_rays(scene.camera, dtype)
    hits = intersect_unit_sphere(rays)
    normal, view = hits.point, -rays.direction
    radiance = jnp.zeros(normal.shape, dtype=dtype)
    seen = sample_lights(scene.lights, hits.point)
    if seen is not None:
        terms = reflectance.terms(normal[..., None, :], seen.to_light, view[..., None, :])
        per_light = reflectance.radiance(x, terms)  # (H, W, K, 3)
        radiance = radiance + jnp.sum(per_light * (seen.irradiance[..., None] * seen.color), axis=-2)
    if scene.lights.ambient is not None:
        radiance = radiance + scene.lights.ambient * reflectance.ambient(x)
    miss = background_radiance(scene.background, rays)
    return jnp.where(hits.hit[..., None], radiance, miss), hits.hit

r"""Light sources: ambient, directional and point lights (any number of each).

Lights of one kind are stored together as arrays with a leading light axis, so that a
renderer evaluates all of them at once by broadcasting rather than by a Python loop. A
kind a scene does not have is ``None`` and costs nothing.

A point light at distance d is attenuated by :math:`1/(c_0 + c_1 d + c_2 d^2)`.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
from jax import Array
from jax.typing import ArrayLike

from ..numerics import dot, safe_divide, safe_normalize
from ..precision import uses_float64


class DirectionalLights(eqx.Module):
    """K directional lights: ``direction`` (K, 3) unit vectors toward the lights,
    ``intensity`` (K,), ``color`` (K, 3)."""

    direction: Array
    intensity: Array
    color: Array


class PointLights(eqx.Module):
    """K point lights: ``position`` (K, 3), ``intensity`` (K,), ``color`` (K, 3) and
    ``attenuation`` (K, 3) holding (c0, c1, c2)."""

    position: Array
    intensity: Array
    color: Array
    attenuation: Array


class Lights(eqx.Module):
    """All the lights of a scene. ``ambient`` is the summed ambient intensity (scalar)."""

    directional: DirectionalLights | None = None
    point: PointLights | None = None
    ambient: Array | None = None

    @property
    def count(self) -> int:
        """Number of directional and point lights (ambient not counted)."""
        n = 0
        if self.directional is not None:
            n += self.directional.intensity.shape[0]
        if self.point is not None:
            n += self.point.intensity.shape[0]
        return n

    def intensities(self) -> dict[str, Array]:
        """The differentiable intensity arrays, by kind (only the kinds present)."""
        out: dict[str, Array] = {}
        if self.directional is not None:
            out["directional"] = self.directional.intensity
        if self.point is not None:
            out["point"] = self.point.intensity
        if self.ambient is not None:
            out["ambient"] = self.ambient
        return out

    @uses_float64
    def with_intensities(self, intensities: dict[str, ArrayLike]) -> Lights:
        """A copy with the intensities of :meth:`intensities` replaced."""
        lights = self
        if "directional" in intensities:
            lights = eqx.tree_at(lambda l: l.directional.intensity, lights, jnp.asarray(intensities["directional"]))
        if "point" in intensities:
            lights = eqx.tree_at(lambda l: l.point.intensity, lights, jnp.asarray(intensities["point"]))
        if "ambient" in intensities:
            lights = eqx.tree_at(lambda l: l.ambient, lights, jnp.asarray(intensities["ambient"]))
        return lights


class LightSamples(NamedTuple):
    """The directional and point lights as seen from surface points.

    ``to_light`` (..., K, 3) unit vectors; ``irradiance`` (..., K) the intensity after
    attenuation; ``color`` (K, 3). K is the number of directional plus point lights. With
    directional lights only, ``to_light`` is (K, 3) and ``irradiance`` (K,), broadcastable
    against the points' shape.
    """

    to_light: Array
    irradiance: Array
    color: Array


def sample_lights(lights: Lights, position: ArrayLike) -> LightSamples | None:
    """Directions and attenuated intensities of every non-ambient light at ``position``
    (shape ``(..., 3)``); ``None`` if the scene has only ambient light."""
    position = jnp.asarray(position)
    batch = position.shape[:-1]
    to_light, irradiance, color = [], [], []
    if lights.directional is not None:
        d = lights.directional
        k = d.intensity.shape[0]
        to_light.append(jnp.broadcast_to(d.direction, batch + (k, 3)))
        irradiance.append(jnp.broadcast_to(d.intensity, batch + (k,)))
        color.append(d.color)
    if lights.point is not None:
        p = lights.point
        offset = p.position - position[..., None, :]
        distance = jnp.sqrt(dot(offset, offset))
        c0, c1, c2 = p.attenuation[:, 0], p.attenuation[:, 1], p.attenuation[:, 2]
        falloff = c0 + c1 * distance + c2 * distance**2
        to_light.append(safe_normalize(offset))
        irradiance.append(safe_divide(p.intensity, falloff))
        color.append(p.color)
    if not to_light:
        return None
    if len(to_light) == 1 and lights.point is None:
        # directional lights only: keep (K, 3) and let the shading broadcast it, rather
        # than materialising a copy per pixel
        return LightSamples(
            to_light=lights.directional.direction, irradiance=lights.directional.intensity, color=color[0]
        )
    return LightSamples(
        to_light=jnp.concatenate(to_light, axis=-2),
        irradiance=jnp.concatenate(irradiance, axis=-1),
        color=jnp.concatenate(color, axis=0),
    )

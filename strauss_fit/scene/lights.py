r"""Light sources: ambient, directional and point lights (any number of each).

Lights of one kind are stored together as arrays with a leading light axis, so that a
renderer evaluates all of them at once by broadcasting rather than by a Python loop. A
kind a scene does not have is ``None`` and costs nothing.

A point light at distance d is attenuated by `1/(c_0 + c_1 d + c_2 d^2)`.
"""

from __future__ import annotations

from typing import ClassVar, NamedTuple

import equinox as eqx
import jax.numpy as jnp
from jax import Array
from jax.typing import ArrayLike

from .._host_methods import host_method
from ..numerics import dot, safe_divide, safe_normalize
from ..precision import uses_float64


class DirectionalLights(eqx.Module):
    """K directional lights: ``direction`` (K, 3) unit vectors toward the lights,
    ``intensity`` (K,), ``color`` (K, 3)."""

    direction: Array
    intensity: Array
    color: Array

    #: The kind's name in scene files, in `Lights.intensities` and in results.
    KIND: ClassVar[str] = "directional"

    def sample(self, position: Array) -> tuple[Array, Array, Array]:
        """``(to_light, irradiance, color)`` at the points ``position`` (..., 3): the same
        direction and intensity everywhere, broadcast to the points."""
        batch, k = position.shape[:-1], self.intensity.shape[0]
        return (
            jnp.broadcast_to(self.direction, batch + (k, 3)),
            jnp.broadcast_to(self.intensity, batch + (k,)),
            self.color,
        )


class PointLights(eqx.Module):
    """K point lights: ``position`` (K, 3), ``intensity`` (K,), ``color`` (K, 3) and
    ``attenuation`` (K, 3) holding (c0, c1, c2)."""

    position: Array
    intensity: Array
    color: Array
    attenuation: Array

    KIND: ClassVar[str] = "point"

    def sample(self, position: Array) -> tuple[Array, Array, Array]:
        """``(to_light, irradiance, color)`` at the points ``position`` (..., 3): the unit
        vector to each light and its intensity over `c_0 + c_1 d + c_2 d^2`."""
        offset = self.position - position[..., None, :]
        distance = jnp.sqrt(dot(offset, offset))
        c0, c1, c2 = self.attenuation[:, 0], self.attenuation[:, 1], self.attenuation[:, 2]
        falloff = c0 + c1 * distance + c2 * distance**2
        return safe_normalize(offset), safe_divide(self.intensity, falloff), self.color


#: The kinds of light with a direction, in the order their lights are numbered and shaded
#: (a scene's directional lights come first). The ambient light has no direction: it is
#: one summed intensity, `Lights.ambient`. A new kind is a class with ``KIND``,
#: ``intensity`` and ``sample`` added here and as a field of `Lights`.
LIGHT_KINDS: tuple[type[DirectionalLights] | type[PointLights], ...] = (DirectionalLights, PointLights)
#: Every kind's name, the ambient light's last.
KIND_NAMES: tuple[str, ...] = (*(kind.KIND for kind in LIGHT_KINDS), "ambient")


class Lights(eqx.Module):
    """All the lights of a scene. ``ambient`` is the summed ambient intensity (scalar)."""

    directional: DirectionalLights | None = None
    point: PointLights | None = None
    ambient: Array | None = None

    @host_method
    def present(self) -> tuple[DirectionalLights | PointLights, ...]:
        """The lights of the scene with a direction, kind by kind (`LIGHT_KINDS`'
        order), the kinds it does not have left out."""
        found = (getattr(self, kind.KIND) for kind in LIGHT_KINDS)
        return tuple(lights for lights in found if lights is not None)

    @property
    def count(self) -> int:
        """Number of directional and point lights (ambient not counted)."""
        return sum(lights.intensity.shape[0] for lights in self.present())

    @host_method
    def intensities(self) -> dict[str, Array]:
        """The differentiable intensity arrays, by kind (only the kinds present)."""
        out: dict[str, Array] = {lights.KIND: lights.intensity for lights in self.present()}
        if self.ambient is not None:
            out["ambient"] = self.ambient
        return out

    @host_method
    @uses_float64
    def with_intensities(self, intensities: dict[str, ArrayLike]) -> Lights:
        """A copy with the intensities of `intensities` replaced."""
        lights = self
        for kind in LIGHT_KINDS:
            if kind.KIND in intensities:
                new = jnp.asarray(intensities[kind.KIND])
                lights = eqx.tree_at(lambda l, name=kind.KIND: getattr(l, name).intensity, lights, new)
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
    present = lights.present()
    if not present:
        return None
    if len(present) == 1 and isinstance(present[0], DirectionalLights):
        # directional lights only: keep (K, 3) and let the shading broadcast it, rather
        # than materialising a copy per pixel
        only = present[0]
        return LightSamples(to_light=only.direction, irradiance=only.intensity, color=only.color)
    to_light, irradiance, color = zip(*(kind.sample(position) for kind in present))
    return LightSamples(
        to_light=jnp.concatenate(to_light, axis=-2),
        irradiance=jnp.concatenate(irradiance, axis=-1),
        color=jnp.concatenate(color, axis=0),
    )

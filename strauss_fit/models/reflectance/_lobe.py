r"""What Phong and Blinn–Phong share: a coloured diffuse part and one white lobe,
`L = k_d\cos\alpha + k_s\,\mathrm{lobe}_n`, linear in `k_d` (per channel) and
`k_s` (shared) once the exponent n is fixed. Each subclass says what its lobe is."""

from __future__ import annotations

import abc
from collections.abc import Mapping

import jax.numpy as jnp
from jax import Array
from jax.typing import ArrayLike

from ...precision import uses_float64
from ._base import ReflectanceModel, channels, scalar


class DiffuseLobeModel(ReflectanceModel):
    """Abstract: ``diffuse`` (RGB), ``specular`` (white) and the lobe's ``exponent``;
    subclasses give `terms`, `_lobe`, `start_grid` and `_albedo_lobe`."""

    @abc.abstractmethod
    def _lobe(self, exponent: ArrayLike, terms: Mapping[str, Array]) -> Array:
        """The lobe per unit ``specular`` (0 where not lit)."""

    @uses_float64
    def radiance(self, x: Mapping[str, Array], terms: Mapping[str, Array]) -> Array:
        lobe = self._lobe(x["exponent"], terms)
        return terms["cos_alpha"][..., None] * jnp.asarray(x["diffuse"]) + (scalar(x["specular"]) * lobe)[..., None]

    @uses_float64
    def ambient(self, x: Mapping[str, Array]) -> Array:
        return jnp.asarray(x["diffuse"])

    @uses_float64
    def linear_parts(self, nonlinear: Mapping[str, ArrayLike], terms: Mapping[str, Array]) -> tuple[Array, Array]:
        """per_channel cos α (a = k_d), shared the lobe (b = k_s)."""
        lobe = self._lobe(self._nonlinear_values(nonlinear)["exponent"], terms)
        cos_alpha = terms["cos_alpha"]
        return channels(cos_alpha, cos_alpha.shape), channels(lobe, lobe.shape)

    @uses_float64
    def from_linear(
        self, nonlinear: Mapping[str, ArrayLike], a: ArrayLike, b: ArrayLike
    ) -> tuple[dict[str, Array], Array | None]:
        """k_d = a, k_s = b (each at least 0); no scale."""
        values = {**self._nonlinear_values(nonlinear), "diffuse": a, "specular": b}
        return self._complete(values), None

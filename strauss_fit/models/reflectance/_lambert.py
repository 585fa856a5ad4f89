"""Lambert's model: a perfectly diffuse surface."""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar, final

import jax.numpy as jnp
from jax import Array
from jax.typing import ArrayLike

from ...numerics import dot
from ...precision import uses_float64
from ._base import Parameter, ReflectanceModel, channels


def lit_cosines(normal: ArrayLike, to_light: ArrayLike, view: ArrayLike) -> tuple[Array, Array, Array]:
    """``lit`` (N·L > 0 and N·V > 0) and N·L, N·V clamped to [0, 1] there (0 elsewhere)."""
    normal, to_light, view = (jnp.asarray(v) for v in (normal, to_light, view))
    n_dot_l, n_dot_v = dot(normal, to_light), dot(normal, view)
    lit = (n_dot_l > 0) & (n_dot_v > 0)
    zero = jnp.zeros((), dtype=n_dot_l.dtype)
    return lit, jnp.where(lit, jnp.clip(n_dot_l, 0.0, 1.0), zero), jnp.where(lit, jnp.clip(n_dot_v, 0.0, 1.0), zero)


@final
class Lambert(ReflectanceModel):
    r"""`L = \rho\cos\alpha` (the BRDF ρ/π): reciprocal, and its albedo is ρ at every
    angle, so it conserves energy for ρ ≤ 1. ρ is not bounded above (it absorbs the
    image's scale). Ambient: ρ."""

    name: ClassVar[str] = "lambert"
    parameters: ClassVar[tuple[Parameter, ...]] = (
        Parameter(
            "albedo",
            3,
            0.0,
            None,
            0.8,
            "the diffuse reflectance ρ (linear RGB; times the image scale)",
            "a lit surface in view",
        ),
    )
    bounded_scale: ClassVar[bool] = False
    nonlinear: ClassVar[tuple[str, ...]] = ()

    @uses_float64
    def terms(self, normal: ArrayLike, to_light: ArrayLike, view: ArrayLike) -> dict[str, Array]:
        """``lit`` and ``cos_alpha`` (N·L, 0 where not lit)."""
        lit, cos_alpha, _ = lit_cosines(normal, to_light, view)
        return {"lit": lit, "cos_alpha": cos_alpha}

    @uses_float64
    def radiance(self, x: Mapping[str, Array], terms: Mapping[str, Array]) -> Array:
        return terms["cos_alpha"][..., None] * jnp.asarray(x["albedo"])

    @uses_float64
    def ambient(self, x: Mapping[str, Array]) -> Array:
        return jnp.asarray(x["albedo"])

    @uses_float64
    def linear_parts(self, nonlinear: Mapping[str, ArrayLike], terms: Mapping[str, Array]) -> tuple[Array, Array]:
        """per_channel cos α (a = ρ), shared 0 (b is not used)."""
        self._nonlinear_values(nonlinear)
        cos_alpha = terms["cos_alpha"]
        per_channel = channels(cos_alpha, cos_alpha.shape)
        return per_channel, jnp.zeros_like(per_channel)

    @uses_float64
    def from_linear(
        self, nonlinear: Mapping[str, ArrayLike], a: ArrayLike, b: ArrayLike
    ) -> tuple[dict[str, Array], Array | None]:
        """ρ = a (at least 0); no scale."""
        self._nonlinear_values(nonlinear)
        return self._complete({"albedo": a}), None

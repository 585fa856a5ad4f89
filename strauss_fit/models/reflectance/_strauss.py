r"""The Strauss (1990) model behind the `ReflectanceModel` interface.

The radiance is that of `strauss_fit.models.strauss` (docs/model.md), evaluated by its
own functions (`angular_terms`,
`weights_of`, `combine_rgb`)
with a white light: the local model, exact mode.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar, final

import jax.numpy as jnp
from jax import Array
from jax.typing import ArrayLike

from ...numerics import safe_divide
from ...precision import uses_float64
from ..material import FRACTION_NAMES, STRAUSS_PARAMETERS
from ..strauss import AngularTerms, angular_terms, combine_rgb, weights_of
from ._base import Parameter, ReflectanceModel, channels, power_lobe_width, scalar

#: The largest exponent h = 3/(1 − s) whose width the albedo's lobe rule follows (beyond it
#: the lobe carries a negligible share of the energy; s = 1 is a delta carrying none).
_NARROWEST = 1e6


@final
class Strauss(ReflectanceModel):
    r"""Strauss's model: `Q_d + Q_s` of docs/model.md with a white light,

    ```text
    L = (1 - ms)(1 - s^3)(1 - t)\,C\cos\alpha + r_j\cos^h\beta\,[1 + m(1 - F)(C - 1)].
    ```

    The local reflection uses t (it scales the diffuse and the specular base by 1 − t); the
    index of refraction n enters only the transmitted light of the global model, never the
    radiance here. Not reciprocal (j and F depend on the angle of incidence alone).
    Ambient: `r_d C = (1 - s^3)(1 - t) C` (docs/model.md).
    """

    name: ClassVar[str] = "strauss"
    parameters: ClassVar[tuple[Parameter, ...]] = STRAUSS_PARAMETERS
    bounded_scale: ClassVar[bool] = True
    nonlinear: ClassVar[tuple[str, ...]] = FRACTION_NAMES

    @uses_float64
    def terms(self, normal: ArrayLike, to_light: ArrayLike, view: ArrayLike) -> dict[str, Array]:
        """``lit``, ``cos_alpha``, ``cos_beta``, ``fresnel_alpha`` and ``j`` of
        `angular_terms` (exact mode)."""
        return angular_terms(normal, to_light, view)._asdict()

    def _weights(self, x: Mapping[str, ArrayLike], terms: Mapping[str, Array]):
        angular = AngularTerms(*(terms[k] for k in AngularTerms._fields))
        s, m, t = (scalar(x[k]) for k in FRACTION_NAMES)
        return weights_of(s, m, t, angular)

    @uses_float64
    def radiance(self, x: Mapping[str, Array], terms: Mapping[str, Array]) -> Array:
        color = jnp.asarray(x["color"])
        return combine_rgb(self._weights(x, terms), color, jnp.ones(3, dtype=terms["cos_alpha"].dtype))

    @uses_float64
    def ambient(self, x: Mapping[str, Array]) -> Array:
        s, t = scalar(x["smoothness"]), scalar(x["transparency"])
        return (1 - s**3) * (1 - t) * jnp.asarray(x["color"])

    def start_grid(self) -> list[dict[str, float]]:
        """The capture fitter's grid: s ∈ {0.05, …, 0.92} × m ∈ {0, 0.25, …, 1}, t = 0."""
        return [
            {"smoothness": s, "metalness": m, "transparency": 0.0}
            for s in (0.05, 0.3, 0.5, 0.65, 0.75, 0.85, 0.92)
            for m in (0.0, 0.25, 0.5, 0.75, 1.0)
        ]

    @uses_float64
    def linear_parts(self, nonlinear: Mapping[str, ArrayLike], terms: Mapping[str, Array]) -> tuple[Array, Array]:
        r"""With the weights d, r_s, w of `ShadeWeights`,
        `L_c = C_c (d + w) + (r_s - w)`: per_channel d + w, shared r_s − w; a = E·C and
        b = E for the exposure E."""
        w = self._weights(self._nonlinear_values(nonlinear), terms)
        shape = w.diffuse.shape
        return channels(w.diffuse + w.tint, shape), channels(w.specular - w.tint, shape)

    @uses_float64
    def from_linear(
        self, nonlinear: Mapping[str, ArrayLike], a: ArrayLike, b: ArrayLike
    ) -> tuple[dict[str, Array], Array | None]:
        """C = a / b (clipped to [0, 1]), exposure b (at least 0); ior at its default."""
        exposure = jnp.maximum(scalar(b), 0.0)
        color = safe_divide(jnp.asarray(a), exposure)
        return self._complete({**self._nonlinear_values(nonlinear), "color": color}), exposure

    def _albedo_lobe(self, x: Mapping[str, Array], cos_in: Array) -> tuple[str, Array]:
        s = jnp.clip(scalar(x["smoothness"]), 0.0, 1.0)
        exponent = jnp.minimum(safe_divide(3.0, 1 - s, _NARROWEST), _NARROWEST)
        return "mirror", power_lobe_width(exponent)

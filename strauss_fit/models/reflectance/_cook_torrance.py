r"""The Cook–Torrance microfacet model with GGX, separable Smith shadowing and Schlick's Fresnel."""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar, final

import jax.numpy as jnp
from jax import Array
from jax.typing import ArrayLike

from ...numerics import dot, safe_divide, safe_normalize, safe_sqrt
from ...precision import uses_float64
from ._base import Parameter, ReflectanceModel, channels, scalar
from ._lambert import lit_cosines


@final
class CookTorrance(ReflectanceModel):
    r"""Cook–Torrance with a Lambertian base:

    ```text
    f_r = \frac{k_d}{\pi} + \frac{F\,D\,G}{4\,(N\cdot L)(N\cdot V)}, \qquad
    L = \pi f_r \cos\alpha,
    ```

    with H = (L + V)/|L + V| and, for the roughness α:

    - D, GGX: `D = \alpha^2 / (\pi((N\cdot H)^2(\alpha^2 - 1) + 1)^2)`;
    - G, separable Smith with GGX's Λ: `G = G_1(L)\,G_1(V)`,
      `G_1 = 1/(1 + \Lambda)`, `\Lambda(\theta) = (\sqrt{1 + \alpha^2\tan^2\theta} - 1)/2`;
    - F, Schlick's, per channel: `F = F_0 + (1 - F_0)(1 - V\cdot H)^5`.

    Evaluated as `L = k_d\cos\alpha + F\,(\pi D)\,G_1(L)\,G_1(V)/(4\,N\cdot V)`, where
    `G_1(V)/(4 N\cdot V) = 1/(2(c + \sqrt{c^2 + \alpha^2(1 - c^2)}))` (c = N·V) and
    `G_1(L) = 2c'/(c' + \sqrt{c'^2 + \alpha^2(1 - c'^2)})` (c' = N·L): no division by a
    cosine, so value and gradient stay finite at grazing light and view. α = 0 is a delta
    lobe carrying no energy (the radiance is then the diffuse part alone; the division
    0/0 at the exact mirror direction gives 0).

    Reciprocal. With kd = 0 and F0 = 1 (F ≡ 1) the albedo is at most 1 (single scattering
    loses energy at large α); the diffuse part is not weighted by 1 − F, so kd + F0 ≤ 1
    keeps the albedo below 1 near normal incidence only (the tests measure it). Ambient: kd.
    """

    name: ClassVar[str] = "cook-torrance"
    parameters: ClassVar[tuple[Parameter, ...]] = (
        Parameter(
            "kd",
            3,
            0.0,
            1.0,
            0.5,
            "the diffuse albedo (linear RGB)",
            "a lit surface in view; its absolute value a known exposure or highlights near grazing incidence",
        ),
        Parameter(
            "f0",
            3,
            0.0,
            1.0,
            0.04,
            "the specular reflectance at normal incidence F0 (RGB: coloured for metals)",
            "a highlight in view; its absolute value highlights at several angles of incidence (F rises to 1)",
        ),
        Parameter(
            "roughness",
            1,
            0.0,
            1.0,
            0.3,
            "α, the GGX width (0 a mirror, 1 very rough)",
            "a highlight in view, resolved over a few pixels (its width and its tails)",
        ),
    )
    bounded_scale: ClassVar[bool] = True
    nonlinear: ClassVar[tuple[str, ...]] = ("roughness", "f0")

    @uses_float64
    def terms(self, normal: ArrayLike, to_light: ArrayLike, view: ArrayLike) -> dict[str, Array]:
        """``lit``, ``cos_alpha`` (N·L), ``cos_gamma`` (N·V), ``cos_nh`` (N·H) and ``cos_vh``
        (V·H = L·H), each clamped to [0, 1] and 0 where not lit; and the parts of
        `radiance` that do not depend on the parameters (a fit evaluates it hundreds of
        times on the same terms): ``sin2_alpha`` = 1 − (N·L)², ``sin2_gamma`` = 1 − (N·V)²,
        ``cos2_nh`` = (N·H)² and ``schlick`` = (1 − V·H)⁵."""
        normal, to_light, view = (jnp.asarray(v) for v in (normal, to_light, view))
        lit, cos_alpha, cos_gamma = lit_cosines(normal, to_light, view)
        half = safe_normalize(to_light + view)
        zero = jnp.zeros((), dtype=cos_alpha.dtype)
        cos_nh = jnp.where(lit, jnp.clip(dot(normal, half), 0.0, 1.0), zero)
        cos_vh = jnp.where(lit, jnp.clip(dot(view, half), 0.0, 1.0), zero)
        return {
            "lit": lit,
            "cos_alpha": cos_alpha,
            "cos_gamma": cos_gamma,
            "cos_nh": cos_nh,
            "cos_vh": cos_vh,
            "sin2_alpha": 1 - cos_alpha * cos_alpha,
            "sin2_gamma": 1 - cos_gamma * cos_gamma,
            "cos2_nh": cos_nh * cos_nh,
            "schlick": (1 - cos_vh) ** 5,
        }

    def _specular(self, roughness: ArrayLike, terms: Mapping[str, Array]) -> tuple[Array, Array]:
        r"""`(\pi D)\,G_1(L)\,G_1(V)/(4 N\cdot V)` and the Schlick weight
        `(1 - V\cdot H)^5`, each ``(...)``. The first as one quotient,
        `\alpha^2 c' / (q^2 g_L g_V)` with `q = (N\cdot H)^2(\alpha^2 - 1) + 1`,
        `g_L = c' + \sqrt{c'^2 + \alpha^2(1 - c'^2)}` and
        `g_V = c + \sqrt{c^2 + \alpha^2(1 - c^2)}`: one guarded division instead of
        three in the fits' inner loop. The denominator is 0 only where the numerator is too
        (α = 0 at the exact mirror direction, grazing light and view with α = 0, unlit): 0."""
        a2 = scalar(roughness) ** 2
        c_l, c_v = terms["cos_alpha"], terms["cos_gamma"]
        q = terms["cos2_nh"] * (a2 - 1) + 1
        g_l = c_l + safe_sqrt(c_l * c_l + a2 * terms["sin2_alpha"])
        g_v = c_v + safe_sqrt(c_v * c_v + a2 * terms["sin2_gamma"])
        specular = jnp.where(terms["lit"], safe_divide(a2 * c_l, q * q * g_l * g_v), 0.0)
        return specular, terms["schlick"]

    @uses_float64
    def radiance(self, x: Mapping[str, Array], terms: Mapping[str, Array]) -> Array:
        specular, schlick = self._specular(x["roughness"], terms)
        f0 = jnp.asarray(x["f0"])
        fresnel = f0 + (1 - f0) * schlick[..., None]
        return terms["cos_alpha"][..., None] * jnp.asarray(x["kd"]) + fresnel * specular[..., None]

    @uses_float64
    def ambient(self, x: Mapping[str, Array]) -> Array:
        return jnp.asarray(x["kd"])

    def start_grid(self) -> list[dict[str, float]]:
        """α ∈ {0.02, 0.05, 0.1, 0.2, 0.35, 0.5, 0.75, 1} × grey F0 ∈ {0.04 (a dielectric), 0.2, 0.9 (a metal)}."""
        return [
            {"roughness": r, "f0": f} for r in (0.02, 0.05, 0.1, 0.2, 0.35, 0.5, 0.75, 1.0) for f in (0.04, 0.2, 0.9)
        ]

    @uses_float64
    def linear_parts(self, nonlinear: Mapping[str, ArrayLike], terms: Mapping[str, Array]) -> tuple[Array, Array]:
        r"""With α and F0 fixed (F0 a grey number or RGB), `E L_c = (E k_{d,c}) \cos\alpha
        + E\,F_c\,S`: per_channel cos α (a = E·kd), shared F·S with S the specular factor
        (b = E, the exposure). Exact for any F0 given; the start grid gives grey ones."""
        values = self._nonlinear_values(nonlinear)
        specular, schlick = self._specular(values["roughness"], terms)
        f0 = values["f0"]
        fresnel = f0 + (1 - f0) * schlick[..., None]
        cos_alpha = terms["cos_alpha"]
        return channels(cos_alpha, cos_alpha.shape), fresnel * specular[..., None]

    @uses_float64
    def from_linear(
        self, nonlinear: Mapping[str, ArrayLike], a: ArrayLike, b: ArrayLike
    ) -> tuple[dict[str, Array], Array | None]:
        """kd = a / b (clipped to [0, 1]), exposure b (at least 0), α and F0 as given."""
        exposure = jnp.maximum(scalar(b), 0.0)
        kd = safe_divide(jnp.asarray(a), exposure)
        return self._complete({**self._nonlinear_values(nonlinear), "kd": kd}), exposure

    def _albedo_lobe(self, x: Mapping[str, Array], cos_in: Array) -> tuple[str, Array]:
        return "half", jnp.clip(scalar(x["roughness"]), 1e-3, 1.0)

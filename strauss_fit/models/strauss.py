r"""The local Strauss (1990) lighting model, as fixed in docs/model.md.

For unit vectors N (normal), L (toward the light) and V (toward the viewer), with
`\cos\alpha = N\cdot L`, `\cos\gamma = N\cdot V`, `R = 2N(N\cdot L) - L` and
`\cos\beta = \max(R\cdot V, 0)`, one light of colour `C_L` contributes, per unit
intensity,

```text
Q_d C_L + Q_s, \qquad
Q_d = (1 - m s)\, r_d\, C \cos\alpha, \qquad r_d = (1 - s^3)(1 - t),

Q_s = r_s C_s, \quad r_s = r_j \cos^h\beta, \quad h = \frac{3}{1 - s}, \quad
r_j = \min\{1,\ r_n + j\,(r_n + k_j)\}, \quad r_n = (1 - t)\,s^3,

j = F(2\alpha/\pi)\,G(2\alpha/\pi)\,G(2\gamma/\pi), \qquad
C_s = C_L + m\,(1 - F(2\alpha/\pi))\,(C - C_L),
```

and nothing where `N\cdot L \le 0` or `N\cdot V \le 0`. F and G are Strauss's
Fresnel and shadowing approximations (`fresnel`, `shadow`) with
`K_F` = 1.12, `K_G` = 1.01 and `K_J` = 0.1.

The evaluation is split in two stages so that fits can precompute the first once per
scene: `angular_terms` depends only on the geometry (and the evaluation mode), and
`shade_terms` adds the material. `shade` composes them.

At ``s = 1`` the exponent h is infinite and the direct highlight is a delta: it is
`r_j` where `\cos\beta = 1` exactly and 0 elsewhere (no arbitrary large h).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from ..numerics import dot, safe_arccos
from ..precision import uses_float64
from .material import Material

#: Fresnel constant of F(x).
K_F = 1.12
#: Shadowing constant of G(x) (the lecture notes' value; some sources quote 1.02).
K_G = 1.01
#: Constant of the off-specular peak term in r_j.
K_J = 0.1

from .modes import DEFAULT_TABLE_SIZE, MODES, Mode  # noqa: E402 (the evaluator modes, importable without JAX)


@uses_float64
def fresnel(x: ArrayLike) -> Array:
    r"""Strauss's Fresnel approximation, `x \in [0, 1]` the normalised angle 2θ/π.

    `F(x) = \dfrac{(x - k_f)^{-2} - k_f^{-2}}{(1 - k_f)^{-2} - k_f^{-2}}`;
    F(0) = 0, F(1) = 1. Safe for all x in [0, 1] since `k_f > 1`.

    Examples:
        >>> import strauss_fit as sf
        >>> [round(float(sf.fresnel(x)), 4) for x in (0.0, 0.5, 1.0)]
        [0.0, 0.0263, 1.0]
    """
    return _fresnel(jnp.asarray(x))


def _fresnel(x):
    # Factored, (k_f^2 - (x - k_f)^2) = x (2 k_f - x), so F(0) = 0 exactly in any precision
    # and F(x) >= 0 on [0, 1] by construction (two non-negative factors).
    return x * (2 * K_F - x) / (K_F**2 * (x - K_F) ** 2 * _FRESNEL_SCALE)


_FRESNEL_SCALE = (1 - K_F) ** -2 - K_F**-2
_SHADOW_SCALE = (1 - K_G) ** -2 - K_G**-2


def _shadow(x):
    # Factored, (x - k_g)^2 - (1 - k_g)^2 = (x - 1)(x + 1 - 2 k_g): G(1) = 0 exactly in any
    # precision and G(x) >= 0 on [0, 1] (both factors <= 0). The textbook difference of
    # reciprocals rounds to a small negative number at grazing (-2e-6 in float32), which
    # made highlights slightly negative there.
    return (x - 1) * (x + 1 - 2 * K_G) / ((1 - K_G) ** 2 * (x - K_G) ** 2 * _SHADOW_SCALE)


@uses_float64
def shadow(x: ArrayLike) -> Array:
    r"""Strauss's shadowing approximation (the paper's form, not the lecture's misprint).

    `G(x) = \dfrac{(1 - k_g)^{-2} - (x - k_g)^{-2}}{(1 - k_g)^{-2} - k_g^{-2}}`;
    G(0) = 1 (normal incidence), G(1) = 0 (grazing).

    Examples:
        >>> import strauss_fit as sf
        >>> [round(float(sf.shadow(x)), 4) + 0.0 for x in (0.0, 0.5, 1.0)]  # + 0.0: no -0.0
        [1.0, 0.9997, 0.0]
    """
    return _shadow(jnp.asarray(x))


def normalised_angle(cosine: ArrayLike) -> Array:
    """``2 acos(c) / pi`` in [0, 1] for a cosine c clamped to [0, 1] (finite gradient)."""
    c = jnp.clip(jnp.asarray(cosine), 0.0, 1.0)
    # arccos(0) * 2/pi can round to one ulp above 1, outside F's and G's domain.
    return jnp.minimum(safe_arccos(c) * (2.0 / jnp.pi), 1.0)


# --- tabulated modes (the source's speed-ups) -------------------------------------------


@functools.lru_cache(maxsize=32)
def _tables(size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """F and G sampled at ``size`` equally spaced angles over [0, pi/2] (as x = 2θ/π)."""
    if size < 2:
        raise ValueError(f"table size must be at least 2, got {size}")
    x = np.linspace(0.0, 1.0, size)
    return x, _fresnel(x), _shadow(x)


@functools.lru_cache(maxsize=32)
def _j_table(size: int) -> np.ndarray:
    """j(alpha, gamma) = F(a) G(a) G(g) on a ``size`` x ``size`` grid over [0, 1]^2."""
    _, f, g = _tables(size)
    return (f * g)[:, None] * g[None, :]


def _interp_1d(x: Array, table: np.ndarray) -> Array:
    """Linear interpolation of ``table`` (samples at equal steps over [0, 1]) at x in [0, 1]."""
    size = table.shape[0]
    position = jnp.clip(x, 0.0, 1.0) * (size - 1)
    lower = jnp.clip(jnp.floor(position), 0, size - 2)
    frac = position - lower
    index = lower.astype(jnp.int32)
    values = jnp.asarray(table, dtype=x.dtype)
    return values[index] * (1 - frac) + values[index + 1] * frac


def _interp_2d(x: Array, y: Array, table: np.ndarray) -> Array:
    """Bilinear interpolation of a square table over [0, 1]^2."""
    size = table.shape[0]
    px = jnp.clip(x, 0.0, 1.0) * (size - 1)
    py = jnp.clip(y, 0.0, 1.0) * (size - 1)
    lx = jnp.clip(jnp.floor(px), 0, size - 2)
    ly = jnp.clip(jnp.floor(py), 0, size - 2)
    fx, fy = px - lx, py - ly
    ix, iy = lx.astype(jnp.int32), ly.astype(jnp.int32)
    t = jnp.asarray(table, dtype=x.dtype)
    top = t[ix, iy] * (1 - fy) + t[ix, iy + 1] * fy
    bottom = t[ix + 1, iy] * (1 - fy) + t[ix + 1, iy + 1] * fy
    return top * (1 - fx) + bottom * fx


# --- the two stages ---------------------------------------------------------------------


class AngularTerms(NamedTuple):
    """The material-independent factors of one light at one surface point.

    All fields share one broadcast shape ``(...)``. ``lit`` is where N·L > 0 and N·V > 0;
    ``cos_alpha`` and ``cos_beta`` are clamped to [0, 1]; ``fresnel_alpha`` is
    F(2α/π) and ``j`` is F(2α/π) G(2α/π) G(2γ/π) (0 where not lit).
    """

    lit: Array
    cos_alpha: Array
    cos_beta: Array
    fresnel_alpha: Array
    j: Array


def angular_terms(
    normal: ArrayLike,
    to_light: ArrayLike,
    to_eye: ArrayLike,
    mode: Mode = "exact",
    table_size: int = DEFAULT_TABLE_SIZE,
) -> AngularTerms:
    """Compute `AngularTerms` for unit vectors of shape ``(..., 3)`` (broadcasting)."""
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}; expected one of {', '.join(MODES)}")
    normal, to_light, to_eye = (jnp.asarray(v) for v in (normal, to_light, to_eye))
    n_dot_l = dot(normal, to_light)
    n_dot_v = dot(normal, to_eye)
    lit = (n_dot_l > 0) & (n_dot_v > 0)
    reflected = 2 * n_dot_l[..., None] * normal - to_light
    cos_beta = jnp.clip(dot(reflected, to_eye), 0.0, 1.0)
    x_alpha = normalised_angle(n_dot_l)
    x_gamma = normalised_angle(n_dot_v)
    if mode == "exact":
        f_alpha = fresnel(x_alpha)
        j = f_alpha * shadow(x_alpha) * shadow(x_gamma)
    elif mode == "table":
        _, f_table, g_table = _tables(table_size)
        f_alpha = _interp_1d(x_alpha, f_table)
        j = f_alpha * _interp_1d(x_alpha, g_table) * _interp_1d(x_gamma, g_table)
    else:  # "j-table": C_s still needs F(alpha), from a 1-D table of the same size
        _, f_table, _ = _tables(table_size)
        f_alpha = _interp_1d(x_alpha, f_table)
        j = _interp_2d(x_alpha, x_gamma, _j_table(table_size))
    zero = jnp.zeros((), dtype=cos_beta.dtype)
    return AngularTerms(
        lit=lit,
        cos_alpha=jnp.where(lit, jnp.clip(n_dot_l, 0.0, 1.0), zero),
        cos_beta=jnp.where(lit, cos_beta, zero),
        fresnel_alpha=f_alpha,
        j=jnp.where(lit, j, zero),
    )


def diffuse_reflectivity(material: Material) -> Array:
    """`r_d = (1 - s^3)(1 - t)`."""
    s, t = material.smoothness, material.transparency
    return (1 - s**3) * (1 - t)


def specular_base(material: Material) -> Array:
    """`r_n = (1 - t)\\,s^3` (= 1 - t - r_d)."""
    return (1 - material.transparency) * material.smoothness**3


def specular_peak(material: Material, j: ArrayLike) -> Array:
    """`r_j = \\min\\{1, r_n + j (r_n + k_j)\\}`."""
    r_n = specular_base(material)
    return jnp.minimum(1.0, r_n + jnp.asarray(j) * (r_n + K_J))


def highlight_falloff(cos_beta: ArrayLike, smoothness: ArrayLike) -> Array:
    """`\\cos^h\\beta` with `h = 3/(1-s)`, guarded at both ends.

    cos β ≤ 0 gives 0 (the base is clamped before the power). At s = 1 exactly the lobe is a
    delta: 1 where cos β = 1, else 0. Below s = 1 it is ``exp(h log cos β)``, whose gradient
    in s stays finite (at most about ``1/(e (1 - s))``).
    """
    return _falloff(jnp.asarray(cos_beta), jnp.asarray(smoothness))[0]


def _falloff(cos_beta: Array, smoothness: Array, slope: bool = False) -> tuple[Array, Array | None]:
    r"""`highlight_falloff` and, with ``slope``, its derivative in s,
    `\cos^h\beta \log(\cos\beta)\, dh/ds` with `dh/ds = 3/(1 - s)^2 = h^2/3`
    (0 where the value is guarded: cos β ≤ 0, s = 1)."""
    below_one = smoothness < 1
    exponent = 3.0 / (1.0 - jnp.where(below_one, smoothness, 0.0))
    positive = cos_beta > 0
    log_base = jnp.log(jnp.where(positive, cos_beta, 1.0))
    powered = jnp.where(positive, jnp.exp(exponent * log_base), 0.0)
    delta = jnp.where(cos_beta >= 1, 1.0, 0.0).astype(powered.dtype)
    value = jnp.where(below_one, powered, delta)
    if not slope:
        return value, None
    return value, jnp.where(below_one, powered * log_base * (exponent * exponent / 3.0), 0.0)


def specular_color(material: Material, fresnel_alpha: ArrayLike, light_color: ArrayLike) -> Array:
    """`C_s = C_L + m (1 - F) (C - C_L)`, shape ``(..., 3)``."""
    light_color = jnp.asarray(light_color)
    weight = material.metalness * (1 - jnp.asarray(fresnel_alpha))
    return light_color + weight[..., None] * (material.color - light_color)


class ShadeWeights(NamedTuple):
    r"""The scalar weights of one light, shape ``(...)``, such that
    `Q_d C_L + Q_s = d\,(C \circ C_L) + r_s C_L + w\,(C - C_L)`:
    ``diffuse`` d = (1 − m s) r_d cos α, ``specular`` r_s, ``tint`` w = r_s m (1 − F)."""

    diffuse: Array
    specular: Array
    tint: Array


def shade_weights(material: Material, terms: AngularTerms) -> ShadeWeights:
    """`ShadeWeights` from precomputed terms. Why scalars: forming RGB once, by
    broadcasting at the end, is several times faster on XLA:CPU than per-light RGB arrays."""
    return weights_of(material.smoothness, material.metalness, material.transparency, terms)


def weights_of(s: Array, m: Array, t: Array, terms: AngularTerms) -> ShadeWeights:
    """`ShadeWeights` of smoothness ``s``, metalness ``m`` and transparency ``t``."""
    return _weights(s, m, t, terms, slopes=False)[0]


class WeightSlopes(NamedTuple):
    """The derivatives of `ShadeWeights` in s, m and t (each a
    `ShadeWeights` of the same shape)."""

    smoothness: ShadeWeights
    metalness: ShadeWeights
    transparency: ShadeWeights


def weight_slopes(s: Array, m: Array, t: Array, terms: AngularTerms) -> tuple[ShadeWeights, WeightSlopes]:
    r"""The weights (`weights_of`) and their derivatives in s, m and t, in closed form:

    ```text
    \partial_s d = -[m (1 - s^3) + 3 s^2 (1 - m s)] (1 - t) \cos\alpha, \quad
    \partial_m d = -s (1 - s^3)(1 - t)\cos\alpha, \quad
    \partial_t d = -(1 - m s)(1 - s^3)\cos\alpha,

    \partial_s r_s = g\,(1 + j)\,3 s^2 (1 - t)\,P + r_j P \log(\cos\beta)\,\frac{3}{(1 - s)^2},
    \quad \partial_t r_s = -g\,(1 + j)\,s^3 P, \quad \partial_m r_s = 0,

    \partial_\theta w = \partial_\theta r_s\, m (1 - F) \ (\theta = s, t), \quad
    \partial_m w = r_s (1 - F),
    ```

    with `P = \cos^h\beta` and g the slope of the clamp `\min\{1, \cdot\}` (1
    below, 0 above, ½ at the tie, as JAX differentiates ``minimum``). The guards are those
    of `highlight_falloff`: no slope where cos β ≤ 0 or s = 1 (the delta lobe).
    Why: a fit's Jacobian built from these costs about two renders, where forward-mode
    differentiation of the render costs about one per parameter (see
    `strauss_fit.rendering.strauss.direct_radiance`)."""
    return _weights(s, m, t, terms, slopes=True)


def _weights(
    s: Array, m: Array, t: Array, terms: AngularTerms, slopes: bool
) -> tuple[ShadeWeights, WeightSlopes | None]:
    """The one home of the weights' formulas: `weights_of`, and with ``slopes`` the
    derivatives of `weight_slopes` from the same subexpressions."""
    s3 = s**3
    one_minus_t = 1 - t
    r_d = (1 - s3) * one_minus_t  # diffuse_reflectivity
    diffuse = (1 - m * s) * r_d * terms.cos_alpha
    r_n = one_minus_t * s3  # specular_base
    value = r_n + terms.j * (r_n + K_J)
    r_j = jnp.minimum(1.0, value)  # specular_peak
    falloff, falloff_s = _falloff(terms.cos_beta, s, slopes)
    r_s = jnp.where(terms.lit, r_j * falloff, 0.0)
    tint = m * (1 - terms.fresnel_alpha)
    weights = ShadeWeights(diffuse, r_s, r_s * tint)
    if not slopes:
        return weights, None
    cos_alpha = terms.cos_alpha
    d_s = -(m * (1 - s3) + 3 * s**2 * (1 - m * s)) * one_minus_t * cos_alpha
    d_m = -s * r_d * cos_alpha
    d_t = -(1 - m * s) * (1 - s3) * cos_alpha
    # the slope of r_j = min(1, r_n (1 + j) + j k_j) in r_n, as JAX differentiates minimum
    gate = jnp.where(value < 1, 1.0, jnp.where(value == 1, 0.5, 0.0)) * (1 + terms.j)
    rs_s = jnp.where(terms.lit, gate * 3 * s**2 * one_minus_t * falloff + r_j * falloff_s, 0.0)
    rs_t = jnp.where(terms.lit, -gate * s3 * falloff, 0.0)
    return weights, WeightSlopes(
        smoothness=ShadeWeights(d_s, rs_s, rs_s * tint),
        metalness=ShadeWeights(d_m, jnp.zeros_like(r_s), r_s * (1 - terms.fresnel_alpha)),
        transparency=ShadeWeights(d_t, rs_t, rs_t * tint),
    )


def combine_rgb(weights: ShadeWeights, color: Array, light_color: Array) -> Array:
    r"""`d\,(C \circ C_L) + r_s C_L + w\,(C - C_L)`, shape ``(..., 3)``."""
    return (
        weights.diffuse[..., None] * (color * light_color)
        + weights.specular[..., None] * light_color
        + weights.tint[..., None] * (color - light_color)
    )


def shade_terms(material: Material, terms: AngularTerms, light_color: ArrayLike = (1.0, 1.0, 1.0)) -> Array:
    """`Q_d C_L + Q_s` (RGB, per unit light intensity) from precomputed terms."""
    light_color = jnp.asarray(light_color, dtype=terms.cos_alpha.dtype)
    return combine_rgb(shade_weights(material, terms), material.color, light_color)


@uses_float64
def shade(
    material: Material,
    normal: ArrayLike,
    to_light: ArrayLike,
    to_eye: ArrayLike,
    light_color: ArrayLike = (1.0, 1.0, 1.0),
    mode: Mode = "exact",
    table_size: int = DEFAULT_TABLE_SIZE,
) -> Array:
    """Strauss radiance `Q_d C_L + Q_s` per unit light intensity, shape ``(..., 3)``.

    ``normal``, ``to_light`` and ``to_eye`` are unit vectors of shape ``(..., 3)`` and
    broadcast against each other; the result is 0 where N·L ≤ 0 or N·V ≤ 0.

    Modes (the source's speed-ups), with the worst-case absolute error against
    ``"exact"`` over all angles and all materials in range, as measured by
    ``tests/models/test_strauss_model.py::test_table_mode_error_bounds`` in float64:

    - ``"exact"``: F and G evaluated in closed form.
    - ``"table"``: F(2θ/π) and G(2θ/π) tabulated at ``table_size`` equal steps of θ over
      [0, π/2] and linearly interpolated. Worst error 4.3e-2 at 256 entries, 3.1e-3 at
      1024 (the default), 1.6e-4 at 4096.
    - ``"j-table"``: j(α, γ) tabulated on a ``table_size`` × ``table_size`` grid and
      bilinearly interpolated (F for C_s from a 1-D table). Worst error 4.8e-2 at 256,
      3.5e-3 at 1024 (the default; 8 MB in float64), 1.8e-4 at 4096.

    Both table modes err most at grazing angles: with k_g = 1.01, G falls from about 0.5
    to 0 over the last 1 % of the angle range, which equal steps resolve only at large
    sizes (the error falls roughly as 1/size² beyond 1024).
    """
    terms = angular_terms(normal, to_light, to_eye, mode=mode, table_size=table_size)
    return shade_terms(material, terms, light_color)

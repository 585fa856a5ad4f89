r"""The interface every reflectance model implements: `Parameter` and `ReflectanceModel`.

**Convention** (the project's, as in the Strauss model and the capture fitter). Radiance is
given per unit light intensity: a light of intensity I reaching a Lambertian surface of
albedo ρ at incidence θ gives the radiance ρ·cos θ·I. A light of intensity I therefore
delivers the irradiance E = π·I·cos θ, and a model with the BRDF `f_r` gives the
radiance `\pi f_r \cos\theta_i\, I`. The BRDF of a model is ``radiance / (π cos θ_i)``
and its directional–hemispherical reflectance (albedo) is
`\rho(\theta_i) = \frac{1}{\pi\cos\theta_i}\int_H L(\omega_o)\cos\theta_o\,d\omega_o`
(see `strauss_fit.models.albedo`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from ...errors import MaterialError
from ...numerics import dot, safe_divide, safe_normalize, safe_sqrt
from ...precision import uses_float64

# Parameter lives in a module of its own so that the Strauss material can define its
# parameters without importing the reflectance models (which import the material); the
# redundant aliases re-export what was defined here before
from .._parameter import FREE as FREE
from .._parameter import POSITIVE as POSITIVE
from .._parameter import UNIT as UNIT
from .._parameter import Parameter as Parameter

#: Gauss–Legendre nodes per axis of `ReflectanceModel.albedo`'s quadrature rules.
ALBEDO_NODES = 128


def scalar(value: ArrayLike) -> Array:
    """A size-1 parameter as a scalar: shape () (the capture fitter's (1,) is accepted too)."""
    value = jnp.asarray(value)
    return value.reshape(()) if value.shape == (1,) else value


def channels(value: Array, shape: tuple[int, ...]) -> Array:
    """A scalar field ``(...)`` repeated over the three channels, ``(..., 3)``."""
    return jnp.broadcast_to(value[..., None], shape + (3,))


def power_lobe_width(exponent: ArrayLike) -> Array:
    r"""The GGX width a matching a `\cos^n\theta` lobe near its peak (both
    `\approx e^{-n\theta^2/2}` and `e^{-2\theta^2/a^2}`: a = 2/√n), at most 1."""
    return jnp.minimum(1.0, 2.0 / jnp.sqrt(jnp.maximum(jnp.asarray(exponent), 0.0) + 4.0))


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


class ReflectanceModel(eqx.Module):
    r"""A local reflectance model: a differentiable radiance, its parameters and what a fit needs.

    **Convention.** `radiance` is the outgoing radiance per unit light intensity: a
    light of intensity I reaching a Lambertian surface of albedo ρ at incidence θ gives
    ρ·cos θ·I, so a BRDF `f_r` gives `\pi f_r \cos\theta_i`. Vectors are unit
    vectors pointing away from the surface (N normal, L toward the light, V toward the
    viewer), shape ``(..., 3)``, broadcasting; nothing is reflected where N·L ≤ 0 or N·V ≤ 0.

    **Values.** A model's values are a ``dict`` from parameter names to arrays: shape () for
    a number (shape (1,) is accepted too), (3,) for RGB. `from_dict` builds and checks
    one from plain numbers, `to_dict` goes back, `defaults` gives the defaults.

    **Linear starts.** Every model is linear in a per-channel RGB unknown a and one shared
    unknown b once its `nonlinear` parameters are fixed (`linear_parts`,
    `from_linear`); a fit solves a and b by linear least squares on a grid of
    `start_grid`'s values.

    **Precision.** Every public method runs in the float64 scope
    (`uses_float64`), as the library's other entry points do.

    Subclasses are final and have no fields; they set the class variables `name`,
    `parameters`, `bounded_scale` and `nonlinear`.
    """

    #: The registry name, e.g. ``"strauss"``.
    name: eqx.AbstractClassVar[str]
    #: The parameters, in the order used by fits and reports.
    parameters: eqx.AbstractClassVar[tuple[Parameter, ...]]
    #: True when the parameters that scale the radiance are all bounded above (Strauss C ≤ 1,
    #: Cook–Torrance kd, F0 ≤ 1): an image's overall scale then needs a separate exposure.
    bounded_scale: eqx.AbstractClassVar[bool]
    #: The parameters that `linear_parts` takes fixed (the rest are solved linearly).
    nonlinear: eqx.AbstractClassVar[tuple[str, ...]]

    # --- the model ------------------------------------------------------------------------

    def terms(self, normal: ArrayLike, to_light: ArrayLike, view: ArrayLike) -> dict[str, Array]:
        """The material-independent geometry, computed once per (pixel, light) by a fit:
        arrays of the broadcast shape ``(...)``, among them ``lit`` (N·L > 0 and N·V > 0)."""
        raise NotImplementedError

    def radiance(self, x: Mapping[str, Array], terms: Mapping[str, Array]) -> Array:
        """Outgoing radiance per unit (white) light intensity, ``(..., 3)``; 0 where not lit."""
        raise NotImplementedError

    def ambient(self, x: Mapping[str, Array]) -> Array:
        """What the surface reflects of a uniform ambient light of intensity 1, ``(3,)``."""
        raise NotImplementedError

    def linear_parts(self, nonlinear: Mapping[str, ArrayLike], terms: Mapping[str, Array]) -> tuple[Array, Array]:
        """``(per_channel, shared)``, each ``(..., 3)``, such that for the `nonlinear`
        values given, ``a * per_channel + b * shared`` is `radiance` (times the scale
        of `from_linear`) for a per-channel unknown a ``(3,)`` and a shared one b."""
        raise NotImplementedError

    def from_linear(
        self, nonlinear: Mapping[str, ArrayLike], a: ArrayLike, b: ArrayLike
    ) -> tuple[dict[str, Array], Array | None]:
        """All parameter values (clipped to their ranges) from the `nonlinear` values and
        the linear unknowns, and the image scale (exposure) when `bounded_scale`, else
        ``None``."""
        raise NotImplementedError

    def start_grid(self) -> list[dict[str, float]]:
        """Values of the `nonlinear` parameters to start a fit from (one dict per start)."""
        return [{}]

    def _albedo_lobe(self, x: Mapping[str, Array], cos_in: Array) -> tuple[str, Array] | None:
        """The model's highlight for `albedo`'s lobe rule: ``("mirror", a)`` for a lobe
        about the mirror direction R of L, ``("half", a)`` for one in the half vector about N,
        with a GGX width a at least as wide as the lobe; ``None`` for a model without one."""
        return None

    # --- derived --------------------------------------------------------------------------

    @uses_float64
    def albedo(self, x: Mapping[str, Array], cos_in: ArrayLike, nodes: int = ALBEDO_NODES) -> Array:
        r"""Directional–hemispherical reflectance `\rho(\theta_i)`, ``(3,)``, at the
        incidence ``cos_in`` = cos θ_i (a scalar in [0, 1]; 0 gives 0).

        Quadrature over the outgoing hemisphere: product Gauss–Legendre rules of ``nodes``²
        points, one uniform in cos θ_o (exact for a Lambertian term) and, for models with a
        highlight, one distributed as a GGX lobe of a width covering it, about the mirror
        direction or in the half vector (`_albedo_lobe`), combined with the balance heuristic
        of multiple importance sampling — deterministic, so ρ is a smooth function of the
        values. Both rules use the symmetry of isotropic models about the plane of
        incidence. Accuracy at the default `ALBEDO_NODES` (measured against
        `strauss_fit.models.albedo`'s rules and brute force): about 1e-5 relative for
        Phong (n > 0) and 1e-6 absolute for Strauss up to 88°, about 1e-5 for Blinn–Phong and
        Cook–Torrance; exact for Lambert. A Phong exponent of exactly 0 (a highlight that
        steps from k_s to 0 at cos β = 0) is integrated to about 6e-4 only.
        """
        dtype = jnp.result_type(float)
        cos_in = jnp.clip(jnp.asarray(cos_in, dtype=dtype), 0.0, 1.0)
        sin_in = safe_sqrt(1 - cos_in * cos_in)
        zero = jnp.zeros_like(sin_in)
        normal = jnp.asarray([0.0, 0.0, 1.0], dtype=dtype)
        light = jnp.stack([sin_in, zero, cos_in])
        u, v, weight = (jnp.asarray(a, dtype=dtype) for a in _product_rule(nodes))
        phi = jnp.pi * v  # the half plane y >= 0; the weights count both halves
        uniform = _polar(safe_sqrt(1 - u * u), u, phi)  # cos θ_o = u: the density 1/(2π)
        lobe = self._albedo_lobe(x, cos_in)
        if lobe is None:
            radiance = self.radiance(x, self.terms(normal, light, uniform))
            integral = 2 * jnp.pi * jnp.sum((weight * u)[:, None] * radiance, axis=0)
            return safe_divide(integral, jnp.pi * cos_in)
        axis, width = lobe
        a2 = jnp.asarray(width, dtype=dtype) ** 2
        denominator = 1 - u + a2 * u  # tan²θ = a² u / (1 − u): the density D(θ) cos θ
        local = _polar(safe_sqrt(a2 * u / denominator), safe_sqrt((1 - u) / denominator), phi)
        if axis == "half":
            l_dot_h = dot(local, light)
            # H ↦ 2(L·H)H − L maps the half vectors with L·H > 0 one to one onto the outgoing
            # directions; the others give N·o < 0 (N·H, N·L > 0), left out with the horizon below
            lobe_dirs = 2 * l_dot_h[..., None] * local - light
            density = functools.partial(_half_density, a2, light)
        else:
            mirror = jnp.stack([-sin_in, zero, cos_in])
            across = jnp.stack([cos_in, zero, sin_in])
            lobe_dirs = (
                local[..., :1] * across + local[..., 1:2] * jnp.asarray([0.0, 1.0, 0.0]) + local[..., 2:] * mirror
            )
            density = functools.partial(_mirror_density, a2, mirror)
        total = jnp.zeros(3, dtype=dtype)
        for dirs in (uniform, lobe_dirs):
            radiance = self.radiance(x, self.terms(normal, light, dirs))
            cos_out = dirs[..., 2]
            ratio = safe_divide(cos_out, 1 / (2 * jnp.pi) + density(dirs))  # L cos θ_o / (p1 + p2), without L
            ratio = jnp.where(cos_out > 0, ratio, 0.0)
            total = total + jnp.sum((weight * ratio)[:, None] * radiance, axis=0)
        return safe_divide(total, jnp.pi * cos_in)

    # --- values ---------------------------------------------------------------------------

    @property
    def names(self) -> tuple[str, ...]:
        """The parameter names, in order."""
        return tuple(p.name for p in self.parameters)

    def parameter(self, name: str) -> Parameter:
        """The `Parameter` called ``name``."""
        for p in self.parameters:
            if p.name == name:
                return p
        raise MaterialError(f"{self.name} has no parameter {name!r}; expected one of {', '.join(self.names)}")

    @uses_float64
    def defaults(self) -> dict[str, Array]:
        """Every parameter at its default."""
        return {p.name: p.default_value() for p in self.parameters}

    def to_dict(self, x: Mapping[str, ArrayLike]) -> dict[str, Any]:
        """Plain Python values (a float, or a list of 3 floats for RGB), e.g. for JSON."""
        self._check_keys(x)
        out: dict[str, Any] = {}
        for p in self.parameters:
            arr = np.asarray(x[p.name], dtype=np.float64).reshape(-1)
            if arr.size != p.size:
                raise MaterialError(f"{self.name} {p.name} must have {p.size} value(s), got {arr.size}")
            out[p.name] = float(arr[0]) if p.size == 1 else [float(c) for c in arr]
        return out

    @uses_float64
    def from_dict(self, values: Mapping[str, Any]) -> dict[str, Array]:
        """Checked values from plain numbers (a number, or a list of 3 for RGB); every
        parameter must be given, within its range. Errors are one-line
        `MaterialError` messages."""
        if not isinstance(values, Mapping):
            raise MaterialError(f"{self.name} parameters must be a table of values, got {type(values).__name__}")
        self._check_keys(values)
        out = {}
        for p in self.parameters:
            value = values[p.name]
            if p.size == 1 and not _is_number(value):
                raise MaterialError(f"{self.name} {p.name} must be a number, got {value!r}")
            if p.size == 3 and not (
                isinstance(value, (list, tuple)) and len(value) == 3 and all(_is_number(c) for c in value)
            ):
                raise MaterialError(f"{self.name} {p.name} must be a list of 3 numbers, got {value!r}")
            if not p.contains(value):
                per = " per channel" if p.size == 3 else ""
                raise MaterialError(f"{self.name} {p.name} = {value!r} is outside its range {p.span}{per}")
            out[p.name] = jnp.asarray(value, dtype=float)
        return out

    def _check_keys(self, values: Mapping[str, Any]) -> None:
        unknown = sorted(set(values) - set(self.names))
        if unknown:
            raise MaterialError(
                f"unknown {self.name} parameter(s) {', '.join(unknown)}; expected {', '.join(self.names)}"
            )
        missing = [n for n in self.names if n not in values]
        if missing:
            raise MaterialError(f"missing {self.name} parameter(s) {', '.join(missing)}")

    def _nonlinear_values(self, nonlinear: Mapping[str, ArrayLike]) -> dict[str, Array]:
        """The `nonlinear` values given, the defaults for those left out."""
        unknown = sorted(set(nonlinear) - set(self.nonlinear))
        if unknown:
            raise MaterialError(
                f"{', '.join(unknown)} not among {self.name}'s non-linear parameters "
                f"({', '.join(self.nonlinear) or 'none'})"
            )
        out = {}
        for name in self.nonlinear:
            p = self.parameter(name)
            out[name] = jnp.asarray(nonlinear[name], dtype=float) if name in nonlinear else p.default_value()
        return out

    def _complete(self, values: Mapping[str, ArrayLike]) -> dict[str, Array]:
        """``values`` clipped to their ranges, every other parameter at its default, in order."""
        out = {}
        for p in self.parameters:
            if p.name in values:
                value = p.clip(values[p.name])
                out[p.name] = scalar(value) if p.size == 1 else jnp.broadcast_to(value, (3,))
            else:
                out[p.name] = p.default_value()
        return out


# --- quadrature ---------------------------------------------------------------------------


@functools.lru_cache(maxsize=8)
def _product_rule(nodes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss–Legendre nodes (u, v) on [0, 1]² and weights summing to 1."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    x, w = (x + 1) / 2, w / 2
    u, v = np.meshgrid(x, x, indexing="ij")
    return u.ravel(), v.ravel(), np.outer(w, w).ravel()


def _polar(sin_theta: Array, cos_theta: Array, phi: Array) -> Array:
    return jnp.stack([sin_theta * jnp.cos(phi), sin_theta * jnp.sin(phi), cos_theta], axis=-1)


def _ggx(a2: Array, c: Array) -> Array:
    """GGX's D at cos θ = c (0 for c ≤ 0): a²/(π(c²(a² − 1) + 1)²)."""
    c = jnp.clip(c, 0.0, 1.0)
    return jnp.where(c > 0, safe_divide(a2, math.pi * (c * c * (a2 - 1) + 1) ** 2), 0.0)


def _half_density(a2: Array, light: Array, out: Array) -> Array:
    """Density over outgoing directions of the half-vector rule: D(h) cos θ_h / (4 L·H)."""
    half = safe_normalize(light + out)
    c = half[..., 2]
    return safe_divide(_ggx(a2, c) * c, 4 * dot(light, half))


def _mirror_density(a2: Array, mirror: Array, out: Array) -> Array:
    """Density over outgoing directions of the mirror rule: D(R·o) R·o."""
    c = dot(mirror, out)
    return _ggx(a2, c) * jnp.clip(c, 0.0, 1.0)

r"""The Phong lighting model, rendered with the same scenes, cameras and lights as Strauss.

Phong's model is the baseline the Strauss model was designed to replace (see
``docs/model.md``): several *dependent* numeric coefficients instead of intuitive
parameters in [0, 1]. It is offered here so that both models can render the same scenes and
be fitted and compared.

Geometry as in the Strauss model: unit vectors N (normal), L (toward the light), V (toward
the viewer); `R = 2N(N\cdot L) - L` is the mirror direction of L and
`H = (L + V)/|L + V|` the half vector.

Material (`PhongMaterial`):

=================  =============================  ============================================
symbol             field                          range
=================  =============================  ============================================
`k_a`        ``ka``                         scalar or RGB, each ≥ 0 (ambient)
`k_d`        ``kd``                         scalar or RGB, each ≥ 0 (diffuse)
`k_s`        ``ks``                         scalar or RGB, each ≥ 0 (specular)
`n`          ``exponent``                   [0, 10000] (`MAX_EXPONENT`)
`C_d`        ``diffuse_color``              RGB in [0, 1]^3
`C_{sp}`     ``specular_color``             RGB in [0, 1]^3
—                  ``blinn``                      static bool: Blinn–Phong half vector
=================  =============================  ============================================

Radiance (linear RGB, no tone mapping) with ambient intensity `I_a` and lights i of
intensity `I_i` (after a point light's attenuation, as for Strauss) and colour
`C_{L,i}`:

```text
I = k_a I_a C_d + \sum_i I_i\, C_{L,i} \left[k_d C_d \cos\alpha_i
    + k_s C_{sp} \cos^n\beta_i\right],
```

with `\cos\alpha = N\cdot L` and

- Phong (``blinn = False``): `\cos\beta = \max(R\cdot V, 0)`, the angle between the
  mirror direction of L and the view direction;
- Blinn–Phong (``blinn = True``): `\cos\beta = \max(N\cdot H, 0)`.

A light contributes nothing where `N\cdot L \le 0` or `N\cdot V \le 0`.
`\cos\beta` is clamped at 0 *before* the power, and `\cos^n\beta` is 0 where
`\cos\beta = 0` (so for n = 0 the highlight term is `k_s C_{sp}` wherever
`\cos\beta > 0`). The power is evaluated as `\exp(n \log\cos\beta)` behind a
double ``where``, so value and gradient are finite everywhere, in n as well.

Rendering a scene with a Phong material is `strauss_fit.rendering.phong.render_phong`.
"""

from __future__ import annotations

import math
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from ..errors import MaterialError
from ..numerics import dot, is_traced, safe_normalize
from ..precision import uses_float64

#: Largest accepted Phong exponent (beyond it the highlight is narrower than a pixel of any
#: practical image, and float32 underflows).
MAX_EXPONENT = 10000.0
#: Ranges of the scalar-or-RGB coefficients and the exponent, (low, high); ``None``: unbounded.
COEFFICIENT_RANGES: dict[str, tuple[float, float | None]] = {
    "ka": (0.0, None),
    "kd": (0.0, None),
    "ks": (0.0, None),
    "exponent": (0.0, MAX_EXPONENT),
}
COLOR_FIELDS = ("diffuse_color", "specular_color")
#: Names of all Phong parameters (``blinn`` is a structural switch, not a number).
PARAMETER_NAMES = ("ka", "kd", "ks", "exponent", "diffuse_color", "specular_color")


def _plain_within(value: Any, low: float, high: float | None, sizes: tuple[int, ...]) -> bool:
    """Whether ``value`` is a plain Python number (size 0) or list/tuple of numbers of a size
    in ``sizes``, all finite and within [low, high]: the common case, checked without numpy
    (reading a library of 50 000 materials validates 300 000 values)."""
    kind = type(value)
    if kind is float or kind is int:
        items, size = (value,), 0
    elif (kind is list or kind is tuple) and all(type(v) is float or type(v) is int for v in value):
        items, size = value, len(value)
    else:
        return False
    return size in sizes and all(math.isfinite(v) and v >= low and (high is None or v <= high) for v in items)


def _span(low: float, high: float | None) -> str:
    return f"[{low:g}, {'inf' if high is None else f'{high:g}'}]"


def _check_number(name: str, value: Any, *, rgb_allowed: bool) -> None:
    low, high = COEFFICIENT_RANGES[name]
    if _plain_within(value, low, high, (0, 3) if rgb_allowed else (0,)) or is_traced(value):
        return
    span = _span(low, high)
    arr = np.asarray(value, dtype=float)
    if rgb_allowed and arr.ndim > 1:
        raise MaterialError(f"phong {name} must be a number or an RGB triple, got shape {arr.shape}")
    if rgb_allowed and arr.ndim == 1 and arr.shape != (3,):
        raise MaterialError(f"phong {name} must be a number or an RGB triple, got {arr.tolist()}")
    if not rgb_allowed and arr.ndim != 0:
        raise MaterialError(f"phong {name} must be a number, got {arr.tolist()}")
    if not np.all(np.isfinite(arr)):
        raise MaterialError(f"phong {name} must be finite and in {span}, got {arr.tolist()}")
    if np.any(arr < low) or (high is not None and np.any(arr > high)):
        per = " per channel" if arr.ndim else ""
        raise MaterialError(f"phong {name} = {arr.tolist()} is outside its range {span}{per}")


def _check_color(name: str, value: Any) -> None:
    if _plain_within(value, 0.0, 1.0, (3,)) or is_traced(value):
        return
    arr = np.asarray(value, dtype=float)
    if arr.shape != (3,):
        raise MaterialError(f"phong {name} must be an RGB triple, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)) or np.any(arr < 0.0) or np.any(arr > 1.0):
        raise MaterialError(f"phong {name} = {arr.tolist()} is outside its range [0, 1] per channel")


def check_values(
    ka: Any = 1.0,
    kd: Any = 0.7,
    ks: Any = 0.3,
    exponent: Any = 20.0,
    diffuse_color: Any = (1.0, 1.0, 1.0),
    specular_color: Any = (1.0, 1.0, 1.0),
    blinn: bool = False,
) -> None:
    """Validate Phong values as `PhongMaterial` does, without building JAX arrays
    (cheap: for reading thousands of materials from a file)."""
    for name, value in (("ka", ka), ("kd", kd), ("ks", ks)):
        _check_number(name, value, rgb_allowed=True)
    _check_number("exponent", exponent, rgb_allowed=False)
    _check_color("diffuse_color", diffuse_color)
    _check_color("specular_color", specular_color)
    if not isinstance(blinn, (bool, np.bool_)):
        raise MaterialError(f"phong blinn must be true or false, got {blinn!r}")


def _as_float(value: Any, dtype: Any) -> Array:
    arr = jnp.asarray(value, dtype=dtype)
    if not jnp.issubdtype(arr.dtype, jnp.floating):
        arr = arr.astype(jnp.result_type(float))
    return arr


class PhongMaterial(eqx.Module):
    """A Phong material, a JAX pytree usable inside ``jit``, ``grad`` and ``vmap``.

    ``ka``, ``kd`` and ``ks`` are scalars or RGB triples, each ≥ 0; ``exponent`` lies in
    [0, 10000]; ``diffuse_color`` and ``specular_color`` are linear RGB in [0, 1]^3;
    ``blinn`` (static) selects the Blinn–Phong half-vector highlight. Concrete values are
    validated on construction (a `MaterialError` names the field
    and its range); traced values are not checked. See the module docstring for the model.
    """

    ka: Array
    kd: Array
    ks: Array
    exponent: Array
    diffuse_color: Array
    specular_color: Array
    blinn: bool = eqx.field(static=True)

    @uses_float64
    def __init__(
        self,
        ka: Any = 1.0,
        kd: Any = 0.7,
        ks: Any = 0.3,
        exponent: Any = 20.0,
        diffuse_color: Any = (1.0, 1.0, 1.0),
        specular_color: Any = (1.0, 1.0, 1.0),
        blinn: bool = False,
        *,
        dtype: Any = None,
    ):
        check_values(ka, kd, ks, exponent, diffuse_color, specular_color, blinn)
        self.ka = _as_float(ka, dtype)
        self.kd = _as_float(kd, dtype)
        self.ks = _as_float(ks, dtype)
        self.exponent = _as_float(exponent, dtype)
        self.diffuse_color = _as_float(diffuse_color, dtype)
        self.specular_color = _as_float(specular_color, dtype)
        self.blinn = bool(blinn)

    @classmethod
    def from_dict(cls, values: dict[str, Any], *, dtype: Any = None) -> PhongMaterial:
        """Build from a mapping such as a sidecar's ``parameters``.

        Keys: ``ka``, ``kd``, ``ks`` (number or list of 3 numbers), ``exponent`` (number),
        ``diffuse_color``, ``specular_color`` (lists of 3 numbers) and ``blinn`` (bool).
        Unknown keys are an error; missing keys take the constructor defaults.
        """
        allowed = PARAMETER_NAMES + ("blinn",)
        unknown = sorted(set(values) - set(allowed))
        if unknown:
            raise MaterialError(f"unknown phong key(s) {', '.join(unknown)}; expected {', '.join(allowed)}")

        def is_number(v: Any) -> bool:
            return isinstance(v, (int, float)) and not isinstance(v, bool)

        def is_rgb(v: Any) -> bool:
            return isinstance(v, (list, tuple)) and len(v) == 3 and all(is_number(c) for c in v)

        for key, value in values.items():
            if key == "blinn":
                if not isinstance(value, bool):
                    raise MaterialError(f"phong blinn must be true or false, got {value!r}")
            elif key in COLOR_FIELDS:
                if not is_rgb(value):
                    raise MaterialError(f"phong {key} must be a list of 3 numbers, got {value!r}")
            elif key == "exponent":
                if not is_number(value):
                    raise MaterialError(f"phong exponent must be a number, got {value!r}")
            elif not (is_number(value) or is_rgb(value)):
                raise MaterialError(f"phong {key} must be a number or a list of 3 numbers, got {value!r}")
        return cls(**values, dtype=dtype)

    def to_dict(self) -> dict[str, Any]:
        """Plain Python values (floats, lists of floats, a bool), e.g. for JSON.

        A scalar coefficient stays a number and an RGB one a list, so that
        ``PhongMaterial.from_dict(m.to_dict())`` rebuilds ``m`` exactly.
        """
        out: dict[str, Any] = {}
        for name in PARAMETER_NAMES:
            arr = np.asarray(getattr(self, name), dtype=np.float64)
            if arr.ndim == 0:
                value = float(arr)
                out[name] = value if math.isfinite(value) else None
            else:
                out[name] = [float(c) for c in arr.reshape(-1)]
        out["blinn"] = self.blinn
        return out

    @uses_float64
    def astype(self, dtype: Any) -> PhongMaterial:
        """The same material with every leaf cast to ``dtype``."""
        return jax.tree_util.tree_map(lambda x: jnp.asarray(x, dtype=dtype), self)


def coefficient(value: Array) -> Array:
    """A scalar or RGB coefficient shaped to broadcast against ``(..., 3)``."""
    return value[..., None] if value.ndim == 0 else value


def highlight_power(cos_beta: ArrayLike, exponent: ArrayLike) -> Array:
    r"""`\cos^n\beta` for a cosine already clamped at 0: 0 where cos β ≤ 0, else
    `\exp(n \log\cos\beta)`; value and gradient (in cos β and n) are finite."""
    cos_beta = jnp.asarray(cos_beta)
    positive = cos_beta > 0
    log_base = jnp.log(jnp.where(positive, cos_beta, 1.0))
    return jnp.where(positive, jnp.exp(jnp.asarray(exponent) * log_base), 0.0)


@uses_float64
def phong_angles(normal: ArrayLike, to_light: ArrayLike, to_eye: ArrayLike, blinn: bool) -> tuple[Array, Array, Array]:
    """Where a light reaches the surface and the viewer sees it (N·L > 0 and N·V > 0), cos α
    there (0 elsewhere), and cos β: R·V (Phong) or N·H (Blinn–Phong), clamped to [0, 1]."""
    normal, to_light, to_eye = (jnp.asarray(v) for v in (normal, to_light, to_eye))
    n_dot_l = dot(normal, to_light)
    n_dot_v = dot(normal, to_eye)
    lit = (n_dot_l > 0) & (n_dot_v > 0)
    if blinn:
        half = safe_normalize(to_light + to_eye)
        cos_beta = dot(normal, half)
    else:
        reflected = 2 * n_dot_l[..., None] * normal - to_light
        cos_beta = dot(reflected, to_eye)
    cos_beta = jnp.clip(cos_beta, 0.0, 1.0)
    zero = jnp.zeros((), dtype=cos_beta.dtype)
    return lit, jnp.where(lit, jnp.clip(n_dot_l, 0.0, 1.0), zero), cos_beta


def phong_shade(
    material: PhongMaterial,
    normal: ArrayLike,
    to_light: ArrayLike,
    to_eye: ArrayLike,
    light_color: ArrayLike = (1.0, 1.0, 1.0),
) -> Array:
    r"""Phong radiance per unit light intensity, `C_L [k_d C_d \cos\alpha + k_s C_{sp}
    \cos^n\beta]`, shape ``(..., 3)``.

    ``normal``, ``to_light`` and ``to_eye`` are unit vectors of shape ``(..., 3)`` that
    broadcast against each other; the result is 0 where N·L ≤ 0 or N·V ≤ 0. cos β is R·V
    (Phong) or N·H (Blinn–Phong, ``material.blinn``), clamped at 0 before the power.
    The ambient term is not included (see `strauss_fit.rendering.phong.render_phong`).
    """
    lit, cos_alpha, cos_beta = phong_angles(normal, to_light, to_eye, material.blinn)
    zero = jnp.zeros((), dtype=cos_beta.dtype)
    falloff = jnp.where(lit, highlight_power(cos_beta, material.exponent), zero)
    diffuse = coefficient(material.kd) * material.diffuse_color * cos_alpha[..., None]
    specular = coefficient(material.ks) * material.specular_color * falloff[..., None]
    return jnp.asarray(light_color, dtype=cos_beta.dtype) * (diffuse + specular)

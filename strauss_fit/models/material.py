"""The Strauss material: colour C, smoothness s, metalness m, transparency t, ior n."""

from __future__ import annotations

import math
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from .._host_methods import host_method
from ..errors import MaterialError
from ..numerics import device_array, is_traced
from ..precision import uses_float64
from ._parameter import Parameter

#: The Strauss parameters, in the order used by fits and reports: the one place they are
#: written. The reflectance registry's Strauss model (`strauss_fit.models.reflectance`)
#: holds these very objects; every name list and range below is derived from them.
STRAUSS_PARAMETERS: tuple[Parameter, ...] = (
    Parameter(
        "color",
        3,
        low=0.0,
        high=1.0,
        default=1.0,
        doc="the base colour C (linear RGB)",
        needs="a lit surface in view; its absolute value also a highlight (which fixes the exposure)",
    ),
    Parameter(
        "smoothness",
        1,
        low=0.0,
        high=1.0,
        default=0.5,
        doc="s: 0 matte, 1 a mirror (highlight exponent h = 3/(1 − s))",
        needs="a highlight in view (its width and its strength against the diffuse part)",
    ),
    Parameter(
        "metalness",
        1,
        low=0.0,
        high=1.0,
        default=0.0,
        doc="m: 0 a dielectric, 1 a metal (the highlight takes the colour C)",
        needs="a highlight on a coloured surface (its tint), or the diffuse part's (1 − ms) dimming",
    ),
    Parameter(
        "transparency",
        1,
        low=0.0,
        high=1.0,
        default=0.0,
        doc="t: 0 opaque, 1 fully transparent",
        needs="light through the sphere (a global render); in reflection alone 1 − t scales nearly "
        "everything, as an exposure would",
    ),
    Parameter(
        "ior",
        1,
        low=1.0,
        high=None,
        default=1.5,
        doc="n: the index of refraction (transmission only)",
        needs="a background seen through a transparent sphere (refraction); no effect on reflection",
    ),
)
#: Names of all material parameters, in the order used by fits and reports.
PARAMETER_NAMES = tuple(p.name for p in STRAUSS_PARAMETERS)
#: Ranges of the scalar parameters, (low, high); ``None`` means unbounded.
PARAMETER_RANGES: dict[str, tuple[float, float | None]] = {
    p.name: (p.low, p.high) for p in STRAUSS_PARAMETERS if p.size == 1
}
#: Range of each channel of the colour, (low, high).
COLOR_RANGE = next((p.low, p.high) for p in STRAUSS_PARAMETERS if p.size == 3)
#: s, m, t, n: the parameters that are one number each (a column each in tables and CSVs).
SCALAR_NAMES = tuple(PARAMETER_RANGES)
#: s, m, t: the scalars that are fractions in [0, 1], treated alike by a fit's starts and
#: probes, and the Strauss radiance's non-linear parameters (it is linear in C once they are fixed).
FRACTION_NAMES = tuple(name for name, span in PARAMETER_RANGES.items() if span == (0.0, 1.0))
#: C, s, m, t: what the reflected light depends on (n acts only on light refracted through
#: the sphere), the parameters of a fit of the local model.
REFLECTION_NAMES = tuple(name for name in PARAMETER_NAMES if name != "ior")
#: C, s, m: what a fit of an opaque material frees by default (t = 0, and n then has nothing
#: to act on).
OPAQUE_NAMES = tuple(name for name in REFLECTION_NAMES if name != "transparency")


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


def _check_scalar(name: str, value: Any) -> None:
    low, high = PARAMETER_RANGES[name]
    if _plain_within(value, low, high, (0,)) or is_traced(value):
        return
    arr = np.asarray(value, dtype=float)
    span = f"[{low:g}, {'inf' if high is None else f'{high:g}'}]"
    if not np.all(np.isfinite(arr)):
        raise MaterialError(f"material {name} must be a finite number in {span}, got {value!r}")
    if np.any(arr < low) or (high is not None and np.any(arr > high)):
        raise MaterialError(f"material {name} = {np.asarray(value).tolist()} is outside its range {span}")


def _check_color(value: Any) -> None:
    if _plain_within(value, *COLOR_RANGE, (3,)) or is_traced(value):
        return
    arr = np.asarray(value, dtype=float)
    if arr.shape[-1:] != (3,):
        raise MaterialError(f"material color must be an RGB triple, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)) or np.any(arr < COLOR_RANGE[0]) or np.any(arr > COLOR_RANGE[1]):
        raise MaterialError(f"material color = {arr.tolist()} is outside its range [0, 1] per channel")


def check_values(
    color: Any = (1.0, 1.0, 1.0),
    smoothness: Any = 0.5,
    metalness: Any = 0.0,
    transparency: Any = 0.0,
    ior: Any = 1.5,
) -> None:
    """Validate material values as `Material` does, without building JAX arrays
    (cheap: for reading thousands of materials from a file)."""
    _check_color(color)
    _check_scalar("smoothness", smoothness)
    _check_scalar("metalness", metalness)
    _check_scalar("transparency", transparency)
    _check_scalar("ior", ior)


def _cast(leaf: Any, dtype: Any) -> Array:
    """``jnp.asarray(leaf, dtype)``; a material's few numbers, where concrete and not placed
    on a device of their own, cast on the host (no compiled program)."""
    if isinstance(leaf, jax.Array) and not is_traced(leaf) and leaf.dtype == jnp.dtype(dtype) and not leaf.weak_type:
        return leaf  # already that (``jnp.asarray`` would run a compiled no-op conversion)
    if is_traced(leaf) or (isinstance(leaf, jax.Array) and leaf.committed):
        return jnp.asarray(leaf, dtype=dtype)  # traced or placed: as before
    return device_array(np.asarray(leaf), dtype)


def _as_float(value: Any, dtype: Any) -> Array:
    """A floating-point array (integers such as ``(1, 1, 1)`` become the default float)."""
    if dtype is None and isinstance(value, int) and not isinstance(value, bool):
        # what the conversion below gives an integer (the default float, not weakly typed),
        # without a compiled program
        value = np.float64(value)
    arr = device_array(value, dtype)
    if not jnp.issubdtype(arr.dtype, jnp.floating):
        arr = arr.astype(jnp.result_type(float))
    return arr


class Material(eqx.Module):
    """A Strauss material, a JAX pytree usable inside ``jit``, ``grad`` and ``vmap``.

    ``color`` is linear RGB in [0, 1]^3; ``smoothness``, ``metalness`` and ``transparency``
    lie in [0, 1]; ``ior`` (the index of refraction n) is at least 1. Concrete values are
    validated on construction (a `MaterialError` names the field
    and its range); traced values, e.g. inside a fit or ``jax.grad`` — also a tuple
    holding them, ``Material(color=(p[0], p[1], p[2]))`` — are not checked. Leaves may carry
    leading batch axes (colour ``(..., 3)``, scalars ``(...)``) for ``vmap``.

    Examples:
        >>> import strauss_fit as sf
        >>> copper = sf.Material(color=(0.8, 0.4, 0.2), smoothness=0.7, metalness=0.9)
        >>> float(copper.metalness), copper.color.tolist()
        (0.9, [0.8, 0.4, 0.2])
        >>> sf.Material(smoothness=1.5)
        Traceback (most recent call last):
        ...
        strauss_fit.errors.MaterialError: material smoothness = 1.5 is outside its range [0, 1]
    """

    color: Array
    smoothness: Array
    metalness: Array
    transparency: Array
    ior: Array

    @uses_float64
    def __init__(
        self,
        color: Any = (1.0, 1.0, 1.0),
        smoothness: Any = 0.5,
        metalness: Any = 0.0,
        transparency: Any = 0.0,
        ior: Any = 1.5,
        *,
        dtype: Any = None,
    ):
        check_values(color, smoothness, metalness, transparency, ior)
        self.color = _as_float(color, dtype)
        self.smoothness = _as_float(smoothness, dtype)
        self.metalness = _as_float(metalness, dtype)
        self.transparency = _as_float(transparency, dtype)
        self.ior = _as_float(ior, dtype)

    @classmethod
    def from_dict(cls, values: dict[str, Any], *, dtype: Any = None) -> Material:
        """Build from a mapping such as a scene file's ``[material]`` table or a fit result.

        Unknown keys are an error; missing keys take the constructor defaults.
        """
        unknown = sorted(set(values) - set(PARAMETER_NAMES))
        if unknown:
            raise MaterialError(f"unknown material key(s) {', '.join(unknown)}; expected {', '.join(PARAMETER_NAMES)}")
        for key, value in values.items():
            if key == "color":
                if (
                    not isinstance(value, (list, tuple))
                    or len(value) != 3
                    or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
                ):
                    raise MaterialError(f"material color must be a list of 3 numbers, got {value!r}")
            elif not isinstance(value, (int, float)) or isinstance(value, bool):
                raise MaterialError(f"material {key} must be a number, got {value!r}")
        return cls(**values, dtype=dtype)

    @host_method
    def to_dict(self) -> dict[str, Any]:
        """Plain Python values (lists and floats), e.g. for JSON."""
        out: dict[str, Any] = {"color": [float(c) for c in np.asarray(self.color)]}
        for name in SCALAR_NAMES:
            value = float(np.asarray(getattr(self, name)))
            out[name] = value if math.isfinite(value) else None
        return out

    @host_method
    @uses_float64
    def astype(self, dtype: Any) -> Material:
        """The same material with every leaf cast to ``dtype``."""
        return jax.tree_util.tree_map(lambda x: _cast(x, dtype), self)

"""Guarded elementary functions whose value *and* gradient stay finite.

Every function here uses the double-``where`` pattern: the unsafe argument is first
replaced by a harmless one where it would be singular, the function is evaluated on that,
and the result is then selected. A single ``where`` is not enough, because JAX
differentiates both branches and ``0 * inf = nan`` poisons the gradient.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike


def safe_sqrt(x: ArrayLike) -> Array:
    """``sqrt(max(x, 0))`` with gradient 0 (not ``inf``) where ``x <= 0``."""
    x = jnp.asarray(x)
    positive = x > 0
    x_safe = jnp.where(positive, x, 1.0)
    return jnp.where(positive, jnp.sqrt(x_safe), 0.0)


# asin(a) = a + a z P(z)/Q(z), z = a², for 0 <= a <= 1/2: Cephes asin.c (float64) and
# asinf.c (float32, a plain polynomial).
_ASIN_P = (
    4.253011369004428248960e-3,
    -6.019598008014123785661e-1,
    5.444622390564711410273e0,
    -1.626247967210700244449e1,
    1.956261983317594739197e1,
    -8.198089802484824371615e0,
)
_ASIN_Q = (
    1.0,
    -1.474091372988853791896e1,
    7.049610280856842141659e1,
    -1.471791292232726029859e2,
    1.395105614657485689735e2,
    -4.918853881490881290097e1,
)
_ASIN_P32 = (4.2163199048e-2, 2.4181311049e-2, 4.5470025998e-2, 7.4953002686e-2, 1.6666752422e-1)


def _horner(coefficients: tuple[float, ...], z: Array) -> Array:
    result = jnp.full_like(z, coefficients[0])
    for c in coefficients[1:]:
        result = result * z + c
    return result


def _asin_small(a: Array) -> Array:
    """asin(a) for 0 <= a <= 1/2."""
    z = a * a
    if a.dtype == jnp.float32:
        return a + a * z * _horner(_ASIN_P32, z)
    return a + a * (z * _horner(_ASIN_P, z) / _horner(_ASIN_Q, z))


def safe_arccos(x: ArrayLike) -> Array:
    """``arccos(clip(x, -1, 1))`` with finite gradient at and beyond ``|x| = 1``.

    The exact derivative ``-1/sqrt(1 - x^2)`` is infinite at ``|x| = 1``; there the
    gradient is taken as 0, the value as 0 or pi. Evaluated with Cephes' rational
    approximation (acos c = π/2 − asin c for |c| ≤ ½, 2 asin √((1 − c)/2) above), as accurate
    as ``jnp.arccos`` (≤ 1.4e-7 in float32, 2.2e-16 in float64) but vectorisable: XLA:CPU
    evaluates ``jnp.arccos`` element by element through atan2, slower than NumPy.
    """
    x = jnp.asarray(x)
    inside = jnp.abs(x) < 1
    c = jnp.abs(jnp.where(inside, x, 0.0))
    big = c > 0.5
    w = 0.5 * (1 - c)
    positive = w > 0
    root = jnp.where(positive, jnp.sqrt(jnp.where(positive, w, 1.0)), 0.0)
    a = _asin_small(jnp.where(big, root, c))
    angle = jnp.where(big, 2 * a, np.pi / 2 - a)  # arccos(|x|)
    angle = jnp.where(x < 0, np.pi - angle, angle)
    edge = jnp.where(x >= 1, 0.0, jnp.pi).astype(x.dtype)
    return jnp.where(inside, angle, edge)


def safe_divide(numerator: ArrayLike, denominator: ArrayLike, fallback: ArrayLike = 0.0) -> Array:
    """``numerator / denominator`` where ``denominator != 0``, else ``fallback``."""
    denominator = jnp.asarray(denominator)
    nonzero = denominator != 0
    denominator_safe = jnp.where(nonzero, denominator, 1.0)
    return jnp.where(nonzero, numerator / denominator_safe, fallback)


def safe_normalize(v: ArrayLike, axis: int = -1) -> Array:
    """``v / |v|`` along ``axis``; the zero vector maps to the zero vector."""
    v = jnp.asarray(v)
    norm_sq = dot(v, v)[..., None] if axis in (-1, v.ndim - 1) else jnp.sum(v * v, axis=axis, keepdims=True)
    nonzero = norm_sq > 0
    inv = jnp.where(nonzero, 1.0 / jnp.sqrt(jnp.where(nonzero, norm_sq, 1.0)), 0.0)
    return v * inv


def dot(a: ArrayLike, b: ArrayLike) -> Array:
    """Dot product over the last axis (of size 3), broadcasting the leading ones.

    Written out by component: XLA:CPU turns a size-3 ``sum`` reduction into a slow library
    call that dominated the renderer's time in float32.
    """
    a, b = jnp.asarray(a), jnp.asarray(b)
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def is_traced(tree: Any) -> bool:
    """Whether any leaf of ``tree`` is a traced value (inside ``jit``, ``grad`` or a fit):
    such values cannot be checked or turned into NumPy numbers. A tuple such as
    ``(p[0], p[1], p[2])`` inside ``jax.grad`` is traced through its elements."""
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(tree))


def device_array(value: Any, dtype: Any = None) -> Array:
    """``jnp.asarray(value, dtype)`` without running a compiled program where ``value`` is
    concrete (a Python number, a list or tuple of them, a NumPy array).

    ``jnp.asarray`` of such a value runs a small XLA program (``stage``,
    ``convert_element_type``) for each new shape and dtype it meets: on a cold start each one
    is traced, compiled and written to the compilation cache, and every later process reads
    it back — a dozen of them cost a command about 0.1 s before it had done anything. Here
    the value is copied by NumPy (never shared: a later change to the caller's array must not
    reach the device array) and put on the device (`jax.device_put`), with the dtype and
    weak type ``jnp.asarray`` gives it (a Python number stays weakly typed, so that float32
    work is not promoted to float64 by it). Everything else goes through ``jnp.asarray``:
    JAX arrays, traced values, lists that hold anything but Python numbers (JAX's dtype rules
    for mixed lists are its own), and integers that would be narrowed (JAX refuses values
    out of range where NumPy would wrap them)."""
    if dtype is None and isinstance(value, _PYTHON_NUMBERS):
        return jax.device_put(value)  # weakly typed, the default width: as jnp.asarray
    if isinstance(value, (np.ndarray, np.generic, *_PYTHON_NUMBERS)) or _python_numbers_only(value):
        array = np.array(value, dtype=dtype)  # a copy
        if array.dtype.kind in "biufc":
            canonical = jax.dtypes.canonicalize_dtype(array.dtype)
            if array.dtype.kind not in "iu" or canonical.itemsize >= array.dtype.itemsize:
                return jax.device_put(array.astype(canonical, copy=False))
    return jnp.asarray(value, dtype=dtype)


_PYTHON_NUMBERS = (bool, int, float, complex)


def _python_numbers_only(value: Any) -> bool:
    """Whether ``value`` is a list or tuple (nested or not) of Python numbers only."""
    if isinstance(value, (list, tuple)):
        return all(isinstance(item, _PYTHON_NUMBERS) or _python_numbers_only(item) for item in value)
    return False


def ones_like(value: Any) -> Array:
    """``jnp.ones_like(value)`` (same shape, dtype and weak type) without a compiled program
    where ``value`` is concrete (see `device_array`)."""
    if isinstance(value, jax.core.Tracer) or not isinstance(value, jax.Array) or (value.weak_type and value.ndim):
        return jnp.ones_like(value)
    if value.weak_type:  # a weakly typed number: from a Python one
        one = jax.device_put(value.dtype.type(1).item())
        return one if one.dtype == value.dtype else jnp.ones_like(value)
    return jax.device_put(np.ones(value.shape, dtype=value.dtype))


def _without_directions(fn: Callable[[Array], Array], x: Array) -> tuple[Array, Array]:
    """``fn(x)`` and its empty (0, M) Jacobian: no direction, so no pass to take the value from."""
    value = fn(x)
    return value, jnp.zeros((0, *value.shape), dtype=value.dtype)


def value_and_jacobian_columns(fn: Callable[[Array], Array], x: Array) -> tuple[Array, Array]:
    r"""``fn(x)`` (a flat (M,) output) and its Jacobian at ``x`` (P,) as its P columns
    `\partial f/\partial x_p` stacked into (P, M): forward-mode, one direction after the
    other (``lax.map``), not vmapped over the directions as ``jax.jacfwd`` is.

    Why: a loop's outputs are buffers in memory. ``jacfwd``'s output, and ``fn(x)``'s, are
    fusions that XLA's CPU compiler copies into every consumer, so a program that takes
    several weighted products of one Jacobian (the noise sandwich: the Gauss–Newton bread,
    the meat, JᵀJ twice) evaluated the render and its derivatives once per product: 36 ms
    against 18-26 ms for the whole sandwich of a 256² sphere (P = 5, 2026-12-04). Alone,
    the loop costs what ``jacfwd`` does (1.7 ms): the render's derivatives are closed-form,
    so the directions share little. ``fn`` is evaluated in every direction's pass anyway
    (it is the forward pass of the derivative); the first pass's value is returned."""
    if x.shape[0] == 0:
        return _without_directions(fn, x)
    basis = jnp.eye(x.shape[0], dtype=x.dtype)
    values, columns = jax.lax.map(lambda direction: jax.jvp(fn, (x,), (direction,)), basis)
    return values[0], columns


def value_and_jacobian_rows(fn: Callable[[Array], Array], x: Array) -> tuple[Array, Array]:
    r"""``fn(x)`` (a flat (M,) output) and its Jacobian at ``x`` (P,) as (P, M), like
    `value_and_jacobian_columns`, but with the P directions vmapped (as ``jax.jacfwd``:
    one forward pass for all of them) and the value and Jacobian then materialised
    (``lax.optimization_barrier``), so that the products that read them read buffers.

    Which to use is measured, not argued: in the polish's Gauss–Newton loop (three products
    of one Jacobian per step) this took 16.7 ms a round against 23.7 ms by columns; in the
    noise sandwich, whose second derivatives follow, 30 ms against 23.6 ms (256² sphere,
    P = 5, medians of 25 alternated, 2026-12-04)."""
    if x.shape[0] == 0:
        return _without_directions(fn, x)
    basis = jnp.eye(x.shape[0], dtype=x.dtype)
    value, rows = jax.vmap(lambda direction: jax.jvp(fn, (x,), (direction,)), out_axes=(None, 0))(basis)
    return jax.lax.optimization_barrier((value, rows))


#: `high_percentile` sorts every value below this many (NumPy's own partial sort).
_NARROW_FROM = 16_384
#: `high_percentile`'s sample: every this-many-th value.
_SAMPLE_STRIDE = 16


def high_percentile(values: np.ndarray, q: float) -> float:
    """``np.percentile(values, q)`` (linear interpolation, every value flattened; NaN
    where a value is NaN) for a high ``q`` and float64 values, the same number, sooner:
    NumPy partially sorts all N values for the two order statistics it interpolates, where
    only the values above a threshold can hold them. The threshold is the value of a strided sample
    (every 16th) with about twice the needed share above it; the values at or above it
    are selected and partially sorted, and when the sample misjudged (fewer selected
    than needed) NumPy's percentile is taken instead. 0.3 against 1.7 ms for the 98th
    percentile of 196 000 values. The index and interpolation are NumPy's (``(N − 1)q``,
    its two-sided linear interpolation), so the result is NumPy's exactly. Other dtypes
    (NumPy interpolates float32 in float32), few values, a ``q`` below 50 or outside
    [0, 100] (NumPy's error), and values with a NaN or an infinity go to NumPy as given."""
    given = np.asarray(values)
    flat = given.ravel()
    count = flat.size
    if flat.dtype != np.float64 or count < _NARROW_FROM or not 50 <= q <= 100 or not math.isfinite(float(flat.sum())):
        return float(np.percentile(given, q))
    position = (count - 1) * (q / 100)
    below = math.floor(position)
    above = min(below + 1, count - 1)
    needed = count - below  # the values from the lower order statistic up
    sample = flat[::_SAMPLE_STRIDE]
    rank = max(sample.size - 1 - 2 * math.ceil(needed / _SAMPLE_STRIDE) - 8, 0)
    threshold = np.partition(sample, rank)[rank]
    top = flat[flat >= threshold]
    if top.size < needed:
        return float(np.percentile(given, q))
    offset = count - top.size  # the selected values are the largest: ranks offset, ..., N − 1
    top.partition([below - offset, above - offset])
    low, high = float(top[below - offset]), float(top[above - offset])
    gamma = position - below
    difference = high - low
    return high - difference * (1 - gamma) if gamma >= 0.5 else low + difference * gamma

"""Guarded elementary functions whose value *and* gradient stay finite.

Every function here uses the double-``where`` pattern: the unsafe argument is first
replaced by a harmless one where it would be singular, the function is evaluated on that,
and the result is then selected. A single ``where`` is not enough, because JAX
differentiates both branches and ``0 * inf = nan`` poisons the gradient.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array
from jax.typing import ArrayLike


def safe_sqrt(x: ArrayLike) -> Array:
    """``sqrt(max(x, 0))`` with gradient 0 (not ``inf``) where ``x <= 0``."""
    x = jnp.asarray(x)
    positive = x > 0
    x_safe = jnp.where(positive, x, 1.0)
    return jnp.where(positive, jnp.sqrt(x_safe), 0.0)


def safe_arccos(x: ArrayLike) -> Array:
    """``arccos(clip(x, -1, 1))`` with finite gradient at and beyond ``|x| = 1``.

    The exact derivative ``-1/sqrt(1 - x^2)`` is infinite at ``|x| = 1``; there the
    gradient is taken as 0, the value as 0 or pi.
    """
    x = jnp.asarray(x)
    inside = jnp.abs(x) < 1
    x_safe = jnp.where(inside, x, 0.0)
    edge = jnp.where(x >= 1, 0.0, jnp.pi).astype(x.dtype)
    return jnp.where(inside, jnp.arccos(x_safe), edge)


def safe_divide(numerator: ArrayLike, denominator: ArrayLike, fallback: ArrayLike = 0.0) -> Array:
    """``numerator / denominator`` where ``denominator != 0``, else ``fallback``."""
    denominator = jnp.asarray(denominator)
    nonzero = denominator != 0
    denominator_safe = jnp.where(nonzero, denominator, 1.0)
    return jnp.where(nonzero, numerator / denominator_safe, fallback)


def safe_normalize(v: ArrayLike, axis: int = -1) -> Array:
    """``v / |v|`` along ``axis``; the zero vector maps to the zero vector."""
    v = jnp.asarray(v)
    norm_sq = jnp.sum(v * v, axis=axis, keepdims=True)
    nonzero = norm_sq > 0
    inv = jnp.where(nonzero, 1.0 / jnp.sqrt(jnp.where(nonzero, norm_sq, 1.0)), 0.0)
    return v * inv


def dot(a: ArrayLike, b: ArrayLike) -> Array:
    """Dot product over the last axis, broadcasting the leading ones."""
    return jnp.sum(jnp.asarray(a) * jnp.asarray(b), axis=-1)

r"""The Laplace (Gauss–Newton) approximation: JᵀJ → covariance → deviations and correlations.

The one home of that computation, for every part of the library that needs it: the fit's
uncertainties (:func:`problem_laplace`), the sampler's starting spread and the report
(:func:`laplace_covariance`), the Phong fit, the study's Fisher information and the
identifiability analysis.

At a least-squares optimum :math:`\hat\theta` of residuals :math:`r(\theta)` with Jacobian
J (with respect to the *physical* parameters), the Fisher information of Gaussian noise
of standard deviation σ is :math:`\mathcal I = J^\top J/\sigma^2` and the Laplace
covariance its inverse, :math:`\Sigma = \sigma^2 (J^\top J)^{-1}` — exact for a linear
model with a flat prior and an optimum away from the bounds. σ² is given, or estimated as
:math:`\mathrm{RSS}/(N - P)` (:func:`residual_variance`). The inverse is a pseudo-inverse
(:func:`covariance`, eigenvalues below ``rcond`` times the largest dropped), or, with a
``ridge``, the inverse of :math:`\mathcal I + \epsilon I`, which shows an exact degeneracy
as an enormous deviation instead of dropping it. Deviations are
:math:`\sqrt{\max(\Sigma_{ii}, 0)}` and correlations
:math:`\Sigma_{ij}/(s_i s_j)` (:func:`deviations`, :func:`correlation`).

Problems are duck-typed: anything with ``residual_physical(x)`` (a Strauss
:class:`strauss_fit.fit.problem.Problem`, a Phong
:class:`strauss_fit.convert.phong_fit.PhongProblem`).
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..precision import uses_float64

#: Eigenvalues of JᵀJ below this fraction of the largest are dropped by the pseudo-inverse.
PINV_RCOND = 1e-14


@eqx.filter_jit
def _jacobian(problem: Any, x: Array) -> Array:
    return jax.jacfwd(problem.residual_physical)(x)


@uses_float64
def jacobian(problem: Any, x: Array) -> Array:
    """d(residuals)/d(physical parameters) at ``x``, (N, P): ``jax.jacfwd`` of
    ``problem.residual_physical``, compiled once per problem structure."""
    return _jacobian(problem, x)


def information(jac: np.ndarray) -> np.ndarray:
    """JᵀJ of a Jacobian (N, P)."""
    return jac.T @ jac


def residual_variance(rss: float, count: int, parameters: int) -> float:
    """σ̂² = RSS/(N − P) (N residuals, P parameters; at least one degree of freedom)."""
    return rss / max(count - parameters, 1)


def covariance(
    information: np.ndarray, variance: float = 1.0, *, rcond: float = PINV_RCOND, ridge: float | None = None
) -> np.ndarray:
    """Σ = variance × (JᵀJ)⁺ (Hermitian pseudo-inverse with ``rcond``), or with ``ridge``
    ε the plain inverse variance × (JᵀJ + ε I)⁻¹."""
    if ridge is not None:
        return variance * np.linalg.inv(information + ridge * np.eye(len(information)))
    return variance * np.linalg.pinv(information, rcond=rcond, hermitian=True)


def deviations(cov: np.ndarray) -> np.ndarray:
    """Standard deviations, sqrt(max(diag Σ, 0))."""
    return np.sqrt(np.maximum(np.diag(cov), 0.0))


def correlation(cov: np.ndarray, *, fallback: np.ndarray | None = None, floor: float | None = None) -> np.ndarray:
    """Correlation matrix Σᵢⱼ/(sᵢ sⱼ). Where sᵢ sⱼ = 0 the entry is taken from
    ``fallback`` (default 0); with ``floor``, the denominator is max(sᵢ sⱼ, floor)
    everywhere instead."""
    sd = deviations(cov)
    norm = np.outer(sd, sd)
    if floor is not None:
        return cov / np.maximum(norm, floor)
    out = np.zeros_like(cov) if fallback is None else np.array(fallback, dtype=float)
    return np.divide(cov, norm, out=out, where=norm > 0)


@uses_float64
def problem_laplace(
    problem: Any, x: np.ndarray, rss: float, sigma: float | None = None, info: np.ndarray | None = None
) -> tuple[dict[str, Any], dict[str, Any], np.ndarray | None]:
    r"""The Laplace deviations and correlations of a fit problem at its optimum ``x``.

    :math:`\Sigma = \sigma^2 (J^\top J)^{+}` with σ² given or RSS/(N − P). Entries the
    problem pins at a bound get deviation 0 (their rows and columns of JᵀJ are zeroed).
    ``info``: JᵀJ of the physical residuals at ``x`` if already computed (the polish
    does). Returns the deviations by parameter name (a list for colour), the correlation
    ``{"labels", "matrix"}`` (rounded to 6 digits) and Σ; empty and None for an empty
    layout."""
    layout = problem.layout
    if layout.size == 0:
        return {}, {}, None
    if info is None:
        info = information(np.asarray(jacobian(problem, jnp.asarray(x))))
    free = ~np.asarray(problem.pinned)
    info = np.asarray(info) * np.outer(free, free)
    n, p = problem.target.size, layout.size
    variance = sigma**2 if sigma else residual_variance(rss, n, p)
    cov = covariance(info, variance)
    sd = deviations(cov)
    corr = correlation(cov)
    uncertainty: dict[str, Any] = {}
    for name, size, offset in zip(layout.names, layout.sizes, layout.offsets):
        values = sd[offset : offset + size]
        uncertainty[name] = values.tolist() if size > 1 else float(values[0])
    return uncertainty, {"labels": layout.labels(), "matrix": np.round(corr, 6).tolist()}, cov


@uses_float64
def laplace_covariance(problem: Any, x_hat: np.ndarray, sigma: float) -> np.ndarray:
    """Σ = σ² (JᵀJ)⁺ at ``x_hat``, every entry included (entries the fit pinned at a bound
    too: the sampler needs a scale for them)."""
    j = np.asarray(jacobian(problem, jnp.asarray(x_hat, dtype=jnp.float64)))
    return covariance(information(j), sigma**2)

"""Where the walkers start: how many (`default_walkers`) and where
(`initial_walkers`, the Laplace Gaussian around the fit's optimum folded into the
prior box; "Start" in `strauss_fit.inference.sampler`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ...stats import laplace
from ..posterior import Prior
from ._format import ChainError


def default_walkers(ndim: int) -> int:
    """max(32, 4·P), even (emcee needs at least 2·P walkers; more helps with correlations)."""
    n = max(32, 4 * ndim)
    return n + n % 2


def initial_walkers(
    x_hat: np.ndarray,
    covariance: np.ndarray,
    prior: Prior,
    walkers: int,
    rng: np.random.Generator,
    log_posterior: Callable[[np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """Walkers (W, P) drawn from N(x̂, Σ) as `strauss_fit.inference.sampler` says, strictly inside the
    prior box, redrawn (up to 100 times) where ``log_posterior`` is not finite."""
    x_hat = np.asarray(x_hat, dtype=np.float64)
    width = prior.upper - prior.lower
    sd = laplace.deviations(covariance)
    corr = laplace.correlation(covariance, fallback=np.eye(len(sd)))
    sd = np.clip(np.nan_to_num(sd, nan=0.0, posinf=0.0), 1e-6 * width, 0.25 * width)
    cov = corr * np.outer(sd, sd) + np.diag((1e-9 * width) ** 2)
    try:
        factor = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:  # a correlation of ±1: fall back to the diagonal
        factor = np.diag(sd)
    centre = np.clip(x_hat, prior.lower, prior.upper)
    inset = 1e-6 * width

    def draw(n: int) -> np.ndarray:
        x = centre + rng.standard_normal((n, len(centre))) @ factor.T
        for _ in range(4):  # reflect at the faces (a draw may cross twice if the box is narrow)
            x = np.where(x < prior.lower, 2 * prior.lower - x, x)
            x = np.where(x > prior.upper, 2 * prior.upper - x, x)
        return np.clip(x, prior.lower + inset, prior.upper - inset)

    x = draw(walkers)
    if log_posterior is not None:
        for _ in range(100):
            bad = ~np.isfinite(log_posterior(x))
            if not bad.any():
                break
            x[bad] = draw(int(bad.sum()))
        else:
            raise ChainError("cannot start the walkers: the log-probability is not finite around the fit's optimum")
    return x

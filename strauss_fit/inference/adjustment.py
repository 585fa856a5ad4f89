r"""Adjusting a posterior chain to the fit's noise sandwich, for targets the model cannot
reproduce.

Why. `strauss_fit.inference.sampler.sample` samples the Gaussian likelihood
`\log p = -\mathrm{RSS}(\theta)/(2\sigma^2)` + a flat box prior. Near its optimum that
posterior has the covariance `\Sigma_\text{post} \approx \sigma^2 H^{-1}` (H the
Hessian of ½RSS). When the model cannot reproduce the target, the fitted values do not
scatter like that over fresh noise: their covariance about the *pseudo-true* values (the
best Strauss approximation of the noise-free image) is the noise sandwich
`V = H^{-1} J^\top \Sigma_\varepsilon J H^{-1}` of the fit
(`strauss_fit.stats.laplace.problem_sandwich`), which weighs the noise by where
the Jacobian looks, and the misfit's curvature enters H. On Phong and Mitsuba targets the
variance inflation needed, the generalised eigenvalues of `(\Sigma_\text{post}, V)`,
differed by up to 7× between directions, so one scalar cannot fix it everywhere.

Two adjustments (``sample --adjust``):

- **affine** (the default under mismatch; Chandler & Bate 2007, Ribatet et al. 2012):
  the chain is sampled as usual and mapped on read,
  `\theta' = \hat\theta + A(\theta - \hat\theta)` with
  `A = L_V L_\text{post}^{-1}` (Cholesky factors, `adjustment_matrix`), so that
  `A\Sigma_\text{post}A^\top = V` exactly, `\Sigma_\text{post}` the chain's own
  covariance after burn-in. The chain's shape (skew, curvature) is kept, the raw chain is
  left untouched in the file (resuming is unaffected) and A is stored beside it. Adjusted
  draws that leave the prior box are dropped (a truncated prior) and counted
  (`adjust_samples`). Entries the fit pinned at a bound (V = 0 there) are not
  adjusted.
- **temperature**: one scalar, the likelihood tempered as `L^{1/T}`, i.e. σ → √T σ,
  with `T = \max(1, \lambda_\max)`, `\lambda_\max` the largest generalised
  eigenvalue of (`\Sigma_\text{post}` predicted as `\sigma^2 H^{-1}`, V)
  (`temperature`), both matrices over the same entries — those the fit did not pin
  at a bound, the others held where the fit put them, as the sandwich holds them
  (`strauss_fit.stats.laplace.posterior_covariance`). Every interval is then at
  least as wide as the sandwich's — conservative, and wider than needed in the other
  directions. Tempering only ever widens: where the chain is already at least as wide as V
  in every direction (`\lambda_\max < 1`), T = 1 and the likelihood is left as it
  is, since T < 1 would narrow the chain below the sandwich.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: The ``--adjust`` choices ("auto": "affine" when the fit's uncertainty is the noise
#: sandwich and its verdict is a mismatch, else "none").
METHODS = ("auto", "affine", "temperature", "none")


class AdjustmentError(ValueError):
    """A covariance the adjustment cannot use (not symmetric positive definite)."""


def _cholesky(matrix: np.ndarray, what: str) -> np.ndarray:
    matrix = np.asarray(matrix, dtype=np.float64)
    try:
        return np.linalg.cholesky((matrix + matrix.T) / 2)
    except np.linalg.LinAlgError:
        raise AdjustmentError(f"the {what} is not positive definite") from None


def generalized_eigenvalues(cov_post: np.ndarray, cov_target: np.ndarray) -> np.ndarray:
    r"""The eigenvalues λ of `V v = λ\,\Sigma_\text{post} v`, ascending: the factor by
    which the posterior's variance must grow along each canonical direction to match V."""
    lower = _cholesky(cov_post, "chain's covariance")
    inverse = np.linalg.inv(lower)
    middle = inverse @ np.asarray(cov_target, dtype=np.float64) @ inverse.T
    return np.linalg.eigvalsh((middle + middle.T) / 2)


def temperature(cov_post: np.ndarray, cov_target: np.ndarray) -> float:
    """T = max(1, the largest generalised eigenvalue): the smallest T ≥ 1 with T·Σ_post ⪰ V
    (every linear combination's interval at least as wide as V's). Never below 1: tempering
    is there to widen a chain narrower than the sandwich, and T < 1 would make one that is
    already wide enough narrower than V in some direction. ``cov_post`` and ``cov_target``
    must cover the same entries (a block of one conditional on entries held in the other
    would compare different things)."""
    return max(1.0, float(generalized_eigenvalues(cov_post, cov_target)[-1]))


def adjustment_matrix(cov_post: np.ndarray, cov_target: np.ndarray) -> np.ndarray:
    r"""A with `A\Sigma_\text{post}A^\top = V`: `A = L_V L_\text{post}^{-1}`."""
    return _cholesky(cov_target, "target covariance") @ np.linalg.inv(_cholesky(cov_post, "chain's covariance"))


def adjusted_entries(cov_target: np.ndarray) -> np.ndarray:
    """Which entries are adjusted: those with a positive variance in V (the fit pins the
    others at a bound, where the sandwich gives 0)."""
    return np.diag(np.asarray(cov_target, dtype=np.float64)) > 0


def full_matrix(samples: np.ndarray, cov_target: np.ndarray) -> np.ndarray:
    """The (P, P) adjustment for the chain's draws ``samples`` (n, P): A of
    `adjustment_matrix` on the entries of `adjusted_entries` (their own
    sample covariance as Σ_post), the identity on the others."""
    samples = np.asarray(samples, dtype=np.float64)
    size = samples.shape[1]
    use = adjusted_entries(cov_target)
    out = np.eye(size)
    if use.any():
        post = np.atleast_2d(np.cov(samples[:, use], rowvar=False))
        out[np.ix_(use, use)] = adjustment_matrix(post, np.asarray(cov_target)[np.ix_(use, use)])
    return out


def adjust_samples(
    samples: np.ndarray, center: np.ndarray, matrix: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> tuple[np.ndarray, int]:
    r"""`\theta' = \hat\theta + A(\theta - \hat\theta)` for every draw, keeping only
    those inside the prior box [``lower``, ``upper``]; returns them and how many were
    dropped."""
    samples = np.asarray(samples, dtype=np.float64)
    center = np.asarray(center, dtype=np.float64)
    moved = center + (samples - center) @ np.asarray(matrix, dtype=np.float64).T
    inside = np.all((moved >= lower) & (moved <= upper), axis=1)
    return moved[inside], int(np.sum(~inside))


def loss_of(fit: dict[str, Any]) -> str:
    """The loss a fit result (JSON) minimised (``solver.loss``): ``"linear"`` for least
    squares, and for results written before fits had a choice of loss."""
    loss = (fit.get("solver") or {}).get("loss")
    return str(loss) if loss else "linear"


def default_method(fit: dict[str, Any]) -> tuple[str, str]:
    """The adjustment ``--adjust auto`` picks for a fit result (JSON), and why."""
    method = (fit.get("uncertainty_method") or {}).get("name")
    verdict = (fit.get("residual") or {}).get("verdict")
    if method != "noise sandwich":
        return "none", (
            "the fit's uncertainty is the Laplace approximation (the target's noise was unknown), "
            "which assumes the model reproduces the target: nothing to adjust to"
        )
    if verdict != "mismatch":
        return "none", f"the fit's verdict is '{verdict}': the model reproduces the target, no adjustment needed"
    return "affine", (
        "the model cannot reproduce the target (verdict 'mismatch'): the chain is mapped to the fit's noise "
        "sandwich, the spread of the best Strauss approximation over fresh noise"
    )

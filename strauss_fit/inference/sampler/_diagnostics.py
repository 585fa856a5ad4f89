"""Convergence diagnostics of a chain: autocorrelation times, burn-in, effective sample
sizes, acceptance, and whether the chain can be trusted (the rules are under
"Diagnostics" in `strauss_fit.inference.sampler`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import emcee
import numpy as np

#: A chain is long enough when it is this many times max τ̂ (the stopping rule's default).
DEFAULT_MIN_TAU_MULTIPLE = 50.0
#: Trustworthiness thresholds (see `strauss_fit.inference.sampler`).
MIN_ESS = 100.0
ACCEPTANCE_RANGE = (0.1, 0.9)
STUCK_WALKER = 0.02


@dataclass
class Diagnostics:
    """Convergence diagnostics of a chain (see `strauss_fit.inference.sampler` for the rules)."""

    labels: list[str]
    steps: int
    walkers: int
    tau: list[float]
    burn_in: int
    ess: list[float]
    acceptance_mean: float
    acceptance_min: float
    acceptance_max: float
    tau_multiple: float
    min_tau_multiple: float
    converged: bool
    trustworthy: bool
    reasons: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        """The diagnostics as a JSON-ready dict (the summary's ``diagnostics``)."""
        return asdict(self)


def autocorrelation_times(chain: np.ndarray) -> np.ndarray:
    """τ̂ per parameter of a chain (S, W, P) — emcee's estimator, no length check."""
    tau = emcee.autocorr.integrated_time(chain, c=5, tol=0, quiet=True)
    return np.maximum(np.asarray(tau, dtype=np.float64), 1.0)


def burn_in(tau: np.ndarray, steps: int) -> int:
    """The steps to discard: ⌈2 max τ̂⌉, at most half the chain (so that a short chain keeps
    half its draws)."""
    return int(min(math.ceil(2 * float(np.max(tau))), steps // 2))


def diagnose(
    chain: np.ndarray,
    log_prob: np.ndarray,
    accepted: np.ndarray,
    labels: list[str],
    min_tau_multiple: float = DEFAULT_MIN_TAU_MULTIPLE,
) -> Diagnostics:
    """Diagnostics of a chain (S, W, P) with log-probabilities (S, W) and acceptance counts (W,)."""
    steps, walkers, _ = chain.shape
    tau = autocorrelation_times(chain)
    burn = burn_in(tau, steps)
    ess = walkers * (steps - burn) / tau
    acceptance = accepted / max(steps, 1)
    multiple = steps / float(np.max(tau))
    reasons = []
    converged = multiple >= min_tau_multiple
    if not converged:
        reasons.append(
            f"the chain is {multiple:.0f} autocorrelation times long; at least "
            f"{min_tau_multiple:.0f} are needed (run longer: --resume with a larger --max-steps)"
        )
    low, high = ACCEPTANCE_RANGE
    if not low <= float(np.mean(acceptance)) <= high:
        reasons.append(f"the mean acceptance fraction {np.mean(acceptance):.2f} is outside [{low}, {high}]")
    stuck = int(np.sum(acceptance < STUCK_WALKER))
    if stuck:
        reasons.append(f"{stuck} walker(s) accepted fewer than {STUCK_WALKER:.0%} of their moves (stuck)")
    if float(np.min(ess)) < MIN_ESS:
        worst = labels[int(np.argmin(ess))]
        reasons.append(f"{worst} has only {np.min(ess):.0f} effective samples (fewer than {MIN_ESS:.0f})")
    if not np.all(np.isfinite(log_prob)):
        reasons.append("some stored log-probabilities are not finite")
    return Diagnostics(
        labels=list(labels),
        steps=int(steps),
        walkers=int(walkers),
        tau=tau.tolist(),
        burn_in=burn,
        ess=ess.tolist(),
        acceptance_mean=float(np.mean(acceptance)),
        acceptance_min=float(np.min(acceptance)),
        acceptance_max=float(np.max(acceptance)),
        tau_multiple=float(multiple),
        min_tau_multiple=float(min_tau_multiple),
        converged=bool(converged),
        trustworthy=not reasons,
        reasons=reasons,
    )

"""The noise model a fit uses (`NoiseModel`: Var = a·max(L, 0) + b per channel, plus
quantisation and storage floors), and the range of noise levels a fit accepts
(`NOISE_RANGE`, `check_noise_level`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ...errors import StraussFitError
from ._quantisation import quantisation_sigma

#: Where `describe_noise` got the level from.
NOISE_SOURCES = ("given", "sensor", "image", "unknown")


@dataclass
class NoiseModel:
    r"""The noise of a target image, per value: `\mathrm{Var} = a·\max(L, 0) + b`
    per channel (a: the shot-noise slope, 1/gain; b: additive noise), plus the 8-bit sRGB
    quantisation at the level L when ``quantised``, plus the storage precision
    (``storage`` × |L|)². `sigma_at` evaluates it at a level — the fitted model's
    radiance, the best estimate of the true one.

    ``source``: ``"given"`` (the user's value), ``"sensor"`` (the target's sidecar: the
    synthetic sensor that made it, or a renderer's measured noise), ``"image"`` (estimated
    from the image itself, model-free: `estimate_noise`), ``"unknown"`` (it could not
    be estimated: a noise-free image, or content the estimator cannot separate from
    noise; then `sigma_at` gives NaN). ``relative_stderr`` (3,): the level's own
    uncertainty (0 when given or from a sensor)."""

    source: str
    a: np.ndarray
    b: np.ndarray
    quantised: bool = False
    storage: float = 0.0
    relative_stderr: np.ndarray = field(default_factory=lambda: np.zeros(3))
    notes: list[str] = field(default_factory=list)
    details: dict = field(default_factory=dict)
    #: Why the target's sidecar was not used although there is one (`unusable_sidecar`);
    #: None when there is none, or when it was used.
    sidecar_problem: str | None = None

    @property
    def known(self) -> bool:
        return self.source != "unknown"

    @property
    def signal_dependent(self) -> bool:
        return bool(np.any(self.a > 0))

    def sigma_at(self, level: np.ndarray) -> np.ndarray:
        """σ per value at the radiance ``level`` (..., 3) (NaN when the noise is unknown)."""
        level = np.asarray(level, dtype=np.float64)
        if not self.known:
            return np.full(level.shape, np.nan)
        variance = self.a * np.maximum(level, 0.0) + self.b + (self.storage * level) ** 2
        if self.quantised:
            variance = variance + quantisation_sigma(np.clip(level, 0.0, 1.0)) ** 2
        return np.sqrt(variance)

    def typical(self, level: np.ndarray, sigma: np.ndarray | None = None) -> np.ndarray:
        """(3,) the root-mean-square σ per channel over the values ``level`` (N, 3);
        ``sigma``: σ there when already computed (``sigma_at(level)``)."""
        sigma = self.sigma_at(level) if sigma is None else np.asarray(sigma)
        # Σ σ² per channel as a product over the rows: a mean along axis 0 of (N, 3) is strided
        return np.sqrt(np.einsum("ij,ij->j", sigma, sigma) / len(sigma))

    def to_dict(self) -> dict:
        return {
            "source": self.source,
            "shot_slope": self.a.tolist(),
            "additive_sd": np.sqrt(self.b).tolist(),
            "quantised": self.quantised,
            "storage_precision": self.storage,
            "relative_stderr": np.asarray(self.relative_stderr, dtype=float).tolist(),
            "notes": list(self.notes),
        }


def _triple(value: float | tuple | list | np.ndarray) -> np.ndarray:
    """One value or three (R, G, B) as a fresh (3,) float64 array."""
    return np.broadcast_to(np.asarray(value, dtype=np.float64), (3,)).copy()


#: The noise levels σ (linear units) a fit, a chain or a noise model accepts: from 1e-100
#: to 1e100. Outside, σ² or 1/σ² — and the χ², the noise sandwich and the likelihood built
#: from them with the image's values, pixel counts and slopes — leave float64's range
#: (about 1e±308): a given σ of 1e300 overflowed σ² and made every deviation NaN, one of
#: 1e-300 underflowed σ² to 0 and broke the robust refit. Inside, every product has a
#: hundred orders of magnitude to spare, far beyond any image's scale.
NOISE_RANGE = (1e-100, 1e100)


def check_noise_level(value: float | tuple | list | np.ndarray, what: str = "the noise level") -> np.ndarray:
    """``value``, one noise σ or three (R, G, B), as (3,) float64, or a one-line
    `StraussFitError` naming ``what`` when it is not one or three
    finite numbers within `NOISE_RANGE`."""
    low, high = NOISE_RANGE
    try:
        values = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        values = np.zeros(0)
    if values.size not in (1, 3) or not np.all(np.isfinite(values)) or np.any(values <= 0):
        raise StraussFitError(f"{what} must be one positive number or three (R, G, B), got {value}")
    if np.any(values < low) or np.any(values > high):
        raise StraussFitError(
            f"{what} must be from {low:g} to {high:g} (linear units; beyond, its square or inverse square "
            f"leaves float64's range), got {', '.join(f'{v:g}' for v in values)}"
        )
    return np.broadcast_to(values, (3,)).copy()


def _zero_or_in_range(sigma: float) -> bool:
    """A noise σ of 0 (none) or within `NOISE_RANGE`."""
    return sigma == 0 or (math.isfinite(sigma) and NOISE_RANGE[0] <= sigma <= NOISE_RANGE[1])

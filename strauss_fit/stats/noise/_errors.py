"""The one error the noise estimators raise (a leaf: every estimator module imports it)."""

from __future__ import annotations

from ...errors import StraussFitError


class NoiseEstimationError(StraussFitError):
    """The noise level cannot be estimated from this input."""

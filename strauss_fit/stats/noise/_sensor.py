"""The per-pixel noise of the project's synthetic sensor (`noise_from_sensor`): known,
not estimated, when a target says which sensor made it.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from ._errors import NoiseEstimationError


def noise_from_sensor(
    values: np.ndarray,
    gain: float,
    read_noise: float,
    exposure: float = 1.0,
    *,
    values_are: Literal["recorded", "radiance"] = "recorded",
) -> np.ndarray:
    r"""Per-pixel σ of the project's synthetic sensor, in recorded units.

    Sensor: E = exposure·L, S = Poisson(gain·max(E, 0))/gain (gain 0: S = E),
    O = S + N(0, read_noise²), so Var[O] = max(E, 0)/gain + read_noise².

    ``values_are="recorded"``: ``values`` are the recorded image O (the target, or a model
    of it in the same units) and are the plug-in estimate of E (clipped at 0; exposure is
    already in them and is not used). ``"radiance"``: ``values`` are radiance L and
    E = exposure·L. With the noisy target as the plug-in, E[σ²] is still exact (Var is
    linear in E, clipping at 0 aside) but each pixel's σ is noisy; a model render or a
    smoothed target is a better plug-in.
    """
    if not (np.isfinite(gain) and gain >= 0):
        raise NoiseEstimationError(f"gain must be a finite number >= 0, got {gain!r}")
    if not (np.isfinite(read_noise) and read_noise >= 0):
        raise NoiseEstimationError(f"read_noise must be a finite number >= 0, got {read_noise!r}")
    if not (np.isfinite(exposure) and exposure > 0):
        raise NoiseEstimationError(f"exposure must be a finite number > 0, got {exposure!r}")
    v = np.asarray(values, dtype=np.float64)
    e = np.maximum(v * (exposure if values_are == "radiance" else 1.0), 0.0)
    var = (e / gain if gain > 0 else 0.0) + read_noise**2
    return np.sqrt(var) * np.ones_like(v)

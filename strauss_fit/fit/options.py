"""Settings of a fit (:class:`FitOptions`) and the quality presets.

:data:`QUALITY_PRESETS` is the one table of the ``fast``, ``balanced`` and ``accurate``
presets, read by fits (:meth:`FitOptions.preset`), sampling
(:meth:`strauss_fit.inference.sampler.SampleSettings.preset`) and conversions
(:meth:`strauss_fit.convert.converter.Settings.preset`); the command line's ``--quality``
option only names one. ``FitOptions()`` *is* the ``balanced`` preset, the command line's
default, so that the library and the command line give the same results for the same
preset.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ..errors import StraussFitError
from ..models.strauss import DEFAULT_TABLE_SIZE
from .identifiability import DEFAULT_THRESHOLD

#: Settings of each ``--quality`` preset: for fits (``starts``, ``max_steps``, ``rtol``,
#: ``atol``) and for sampling (``walkers``, ``min_tau_multiple``, ``sample_max_steps``).
#: ``None``: automatic. Derived by benchmarks/tradeoff.py (2026-11-29); the numbers that
#: picked each value are in README.md, "Quality presets".
QUALITY_PRESETS: dict[str, dict[str, float | int | None]] = {
    "fast": dict(
        starts=2, max_steps=20, rtol=1e-2, atol=1e-4, walkers=None, min_tau_multiple=10.0, sample_max_steps=2000
    ),
    "balanced": dict(
        starts=2, max_steps=320, rtol=1e-4, atol=1e-6, walkers=None, min_tau_multiple=50.0, sample_max_steps=10000
    ),
    "accurate": dict(
        starts=4, max_steps=610, rtol=1e-8, atol=1e-10, walkers=128, min_tau_multiple=100.0, sample_max_steps=50000
    ),
}
#: The preset used when none is named (the command line's default, and ``FitOptions()``).
DEFAULT_QUALITY = "balanced"
#: The preset settings that are fit settings (the others are sampling settings).
FIT_PRESET_FIELDS = ("starts", "max_steps", "rtol", "atol")


def quality_preset(name: str) -> dict[str, Any]:
    """A copy of the settings of preset ``name`` (one of :data:`QUALITY_PRESETS`)."""
    if name not in QUALITY_PRESETS:
        raise StraussFitError(f"unknown quality preset {name!r}; expected one of {', '.join(QUALITY_PRESETS)}")
    return dict(QUALITY_PRESETS[name])


_BALANCED = QUALITY_PRESETS[DEFAULT_QUALITY]


@dataclass(frozen=True)
class FitOptions:
    """Settings of a fit; every field is recorded in the result.

    The defaults of ``starts``, ``max_steps``, ``rtol`` and ``atol`` are the ``balanced``
    preset (:data:`QUALITY_PRESETS`); :meth:`preset` gives the others.
    """

    solver: str = "lm"
    starts: int = int(_BALANCED["starts"])
    max_steps: int = int(_BALANCED["max_steps"])
    start_steps: int = 12
    rtol: float = float(_BALANCED["rtol"])
    atol: float = float(_BALANCED["atol"])
    mode: str = "exact"
    table_size: int = DEFAULT_TABLE_SIZE
    free: tuple[str, ...] | None = None
    fixed: tuple[tuple[str, float | tuple[float, ...]], ...] = ()
    fit_lights: bool = False
    reference_noise: float | None = None
    threshold: float = DEFAULT_THRESHOLD

    @classmethod
    def preset(cls, name: str = DEFAULT_QUALITY, **overrides: Any) -> FitOptions:
        """The options of quality preset ``name`` (``fast``, ``balanced`` or ``accurate``),
        with ``overrides`` (any field; a value of None keeps the preset's or the default)."""
        values = {key: quality_preset(name)[key] for key in FIT_PRESET_FIELDS}
        values.update({key: value for key, value in overrides.items() if value is not None})
        return cls(**values)

    def as_dict(self) -> dict[str, Any]:
        return {
            "solver": self.solver,
            "starts": self.starts,
            "max_steps": self.max_steps,
            "start_steps": self.start_steps,
            "rtol": self.rtol,
            "atol": self.atol,
            "mode": self.mode,
            "table_size": self.table_size,
            "free": list(self.free) if self.free is not None else None,
            "fixed": {k: v for k, v in self.fixed},
            "fit_lights": self.fit_lights,
            "reference_noise": self.reference_noise,
            "threshold": self.threshold,
            "precision": "float64",
        }

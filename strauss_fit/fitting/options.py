"""Settings of a fit (`FitOptions`) and the quality presets.

`QUALITY_PRESETS` is the one table of the ``fast``, ``balanced`` and ``accurate``
presets, read by fits (`FitOptions.preset`), sampling
(`strauss_fit.inference.sampler.SampleSettings.preset`) and conversions
(`strauss_fit.convert.converter.Settings.preset`); the command line's ``--quality``
option only names one. ``FitOptions()`` *is* the ``balanced`` preset, the command line's
default, so that the library and the command line give the same results for the same
preset.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any

from ..errors import StraussFitError
from ..models.modes import DEFAULT_TABLE_SIZE
from .losses import LOSS_CHOICES, LOSSES

#: A parameter is fitted when its predicted standard deviation at the reference noise is
#: at most this fraction of its scale (`strauss_fit.fitting.identifiability`).
DEFAULT_THRESHOLD = 0.05

#: Settings of each ``--quality`` preset: for fits (``starts``, ``max_steps``, ``rtol``,
#: ``atol``, ``equivalence``) and for sampling (``walkers``, ``min_tau_multiple``, ``sample_max_steps``).
#: ``None``: automatic. Derived by benchmarks/tradeoff.py (2026-11-29); the numbers that
#: picked each value are in docs/benchmarks.md, "Quality presets".
QUALITY_PRESETS: dict[str, dict[str, float | int | None]] = {
    "fast": dict(
        starts=2,
        max_steps=20,
        rtol=1e-2,
        atol=1e-4,
        equivalence=False,
        walkers=None,
        min_tau_multiple=10.0,
        sample_max_steps=2000,
    ),
    "balanced": dict(
        starts=2,
        max_steps=320,
        rtol=1e-4,
        atol=1e-6,
        equivalence=False,
        walkers=None,
        min_tau_multiple=50.0,
        sample_max_steps=10000,
    ),
    "accurate": dict(
        starts=4,
        max_steps=610,
        rtol=1e-8,
        atol=1e-10,
        equivalence=True,
        walkers=128,
        min_tau_multiple=100.0,
        sample_max_steps=50000,
    ),
}
#: The preset used when none is named (the command line's default, and ``FitOptions()``).
DEFAULT_QUALITY = "balanced"
#: The loss an ``"auto"`` fit switches to when the model cannot reproduce the target
#: (measured on the physically based targets by ``benchmarks/external.py``).
MISMATCH_LOSS = "huber"
#: ... and only when the linear fit's mean CIEDE2000 reaches this (one just-noticeable
#: difference): a mismatch nobody can see (the rim of a Lambertian sphere from a renderer
#: that integrates over each pixel) leaves nothing for another loss to improve.
VISIBLE_DELTA_E = 1.0
#: What ``FitOptions.edge_pixels`` accepts.
EDGE_PIXELS = ("auto", "exclude", "include")
#: What ``FitOptions.solver`` accepts (`strauss_fit.fitting.solvers.solver`): plain names
#: here, so that the command line lists them without importing JAX.
SOLVERS = ("lm", "gauss-newton", "bfgs")
#: What ``FitOptions.search`` accepts: ``"grid"`` (the global search of
#: `strauss_fit.fitting.search` where `grid_applies`, the
#: multi-start elsewhere), ``"starts"`` (the multi-start always) and ``"auto"``, which is
#: ``"grid"``: the grid wherever it applies, as measured by ``benchmarks/search.py``
#: (2026-12-03, preset balanced, both fits of every target interleaved in one process,
#: load average 4-14 on 2 cores; calibrations NumPy 100-356 ms, JAX 34-130 ms):
#:
#: - recovery set, the 95 targets where it applies: the lower RSS of the two reached on 93
#:   against the multi-start's 86, 1 111 solver steps against 1 547, warm time 1.03× (29.6 s
#:   against 28.7 s in all); the 2 it missed are mirrors (s = 1, m = 0) whose colour the
#:   image does not show, where the multi-start's RSS was lower by 1.2e-4 and 9e-6 of itself
#:   (Δχ² 1.05 and 0.10 at the reference noise), decided by which parameters the fit then
#:   held at that degenerate optimum;
#: - bundled Mitsuba renders, the 11 where it applies: the lower RSS on 10 against 8 (every
#:   miss within Δχ² 0.17), 539 steps against 644, but 1.2× the warm time (6.1 s against
#:   5.1 s): short fits, where the grid's fixed cost (four renders of the subsample per s) is
#:   not paid back;
#: - the README's example: the same optimum (RSS 1.99886, 16 steps against 17), and with one
#:   start the grid's reaches it where the multi-start's (the guess, s = 0) ends in the local
#:   minimum at s = 0 (RSS 2.155).
#:
#: So the grid wins on the optimum reached and the steps everywhere it applies and costs
#: time only on short fits; it is the default for its robustness (no start in a basin the
#: fixed points miss). Captures keep their own projected grid (`strauss_fit.fitting.capture`).
SEARCHES = ("auto", "grid", "starts")
#: The preset settings that are fit settings (the others are sampling settings).
FIT_PRESET_FIELDS = ("starts", "max_steps", "rtol", "atol", "equivalence")


def quality_preset(name: str) -> dict[str, Any]:
    """A copy of the settings of preset ``name`` (one of `QUALITY_PRESETS`)."""
    if name not in QUALITY_PRESETS:
        raise StraussFitError(f"unknown quality preset {name!r}; expected one of {', '.join(QUALITY_PRESETS)}")
    return dict(QUALITY_PRESETS[name])


_BALANCED = QUALITY_PRESETS[DEFAULT_QUALITY]


@dataclass(frozen=True)
class FitOptions:
    """Settings of a fit; every field is recorded in the result.

    The defaults of ``starts``, ``max_steps``, ``rtol`` and ``atol`` are the ``balanced``
    preset (`QUALITY_PRESETS`); `preset` gives the others.
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
    #: Also fit one global exposure: a scale on all rendered radiance (every light and the
    #: background together), the usual unknown of a photograph or a foreign render.
    fit_exposure: bool = False
    #: The target's noise standard deviation (linear units; one value or R, G, B, each
    #: within `NOISE_RANGE`) when known; None: from the
    #: target's sidecar, else estimated from the image
    #: (`strauss_fit.stats.noise.describe_noise`).
    noise: float | tuple[float, float, float] | None = None
    #: What the solver minimises (`LOSS_REGISTRY`): ``"linear"``
    #: least squares, ``"perceptual"`` (cube-root), ``"huber"``, ``"cauchy"``; ``"auto"``:
    #: linear, then, if the model cannot reproduce the target visibly, refitted with
    #: `MISMATCH_LOSS` (chosen by ``benchmarks/external.py``, see docs/fitting.md).
    loss: str = "auto"
    #: ``"exclude"``: fit only pixels whose whole footprint shows the sphere (a partly
    #: covered silhouette pixel of an anti-aliased image or a photograph mixes in the
    #: background); ``"include"``: every pixel whose centre shows it; ``"auto"``: include
    #: them when the target's silhouette shows it is point-sampled, else exclude
    #: (`strauss_fit.rendering.coverage.silhouette_blend`; measured by
    #: ``benchmarks/silhouette.py`` and ``benchmarks/recovery.py``, see docs/fitting.md).
    #: A result records what was used.
    edge_pixels: str = "auto"
    #: Also compute each free parameter's perceptual equivalence range
    #: (`strauss_fit.fitting.equivalence.equivalence_ranges`): on in the
    #: ``accurate`` preset.
    equivalence: bool = bool(_BALANCED["equivalence"])
    #: Its threshold, a mean CIEDE2000 (1: one just-noticeable difference).
    equivalence_de: float = 1.0
    #: Where the solves start (`SEARCHES`): ``"grid"``, a global search over
    #: smoothness and metalness with the colour solved in closed form, its best distinct
    #: minima the starts, where that projection holds (an opaque material fitted by least
    #: squares, no light or exposure free), the multi-start elsewhere; ``"starts"``, the
    #: multi-start (the closed-form guess and fixed points) always; ``"auto"``: the grid
    #: wherever it applies, as measured (`SEARCHES`).
    search: str = "auto"

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
            "fit_exposure": self.fit_exposure,
            "noise": list(self.noise) if isinstance(self.noise, tuple) else self.noise,
            "loss": self.loss,
            "edge_pixels": self.edge_pixels,
            "equivalence": self.equivalence,
            "equivalence_de": self.equivalence_de,
            "search": self.search,
            "precision": "float64",
        }

    def validate(self) -> None:
        """Raise `StraussFitError` naming the first bad setting."""
        from ..stats.noise import check_noise_level

        if self.loss not in LOSS_CHOICES:
            raise StraussFitError(f"unknown loss {self.loss!r}; expected one of auto, {', '.join(LOSSES)}")
        if self.search not in SEARCHES:
            raise StraussFitError(f"search must be one of {', '.join(SEARCHES)}, got {self.search!r}")
        if self.edge_pixels not in EDGE_PIXELS:
            raise StraussFitError(f"edge_pixels must be one of {', '.join(EDGE_PIXELS)}, got {self.edge_pixels!r}")
        # the solvers' settings, as the command line's parsers check them (a step limit of 0
        # ran the Gauss-Newton loop, which then reported one evaluation)
        steps = self.max_steps
        if isinstance(steps, bool) or not isinstance(steps, numbers.Integral) or steps < 1:
            raise StraussFitError(f"the solver step limit (max_steps) must be a whole number ≥ 1, got {steps!r}")
        for name in ("rtol", "atol"):
            value = getattr(self, name)
            number = isinstance(value, numbers.Real) and not isinstance(value, bool)
            if not (number and math.isfinite(value) and value >= 0):
                raise StraussFitError(f"the solver tolerance {name} must be a finite number ≥ 0, got {value!r}")
        if self.noise is not None:  # within NOISE_RANGE: beyond, σ² or 1/σ² leaves float64's range
            check_noise_level(self.noise, "the noise level (--noise)")
        if not (math.isfinite(float(self.equivalence_de)) and self.equivalence_de > 0):
            raise StraussFitError(f"the equivalence threshold must be a positive CIEDE2000, got {self.equivalence_de}")
        if self.reference_noise is not None:
            if not (math.isfinite(float(self.reference_noise)) and self.reference_noise > 0):
                raise StraussFitError(f"the reference noise must be a positive number, got {self.reference_noise}")
            check_noise_level(self.reference_noise, "the reference noise (--reference-noise)")

"""Is a capture's material stable? Two disjoint halves of its lights, and each image alone.

- **Halves.** The images are split into two disjoint halves (odd and even), each fitted
  alone, each fit's perceptual equivalence ranges computed
  (`strauss_fit.fitting.capture_equivalence`). The material is *stable* when each half's
  value of every compared parameter (`compared`) lies within the other half's range: the two halves
  then describe materials that look the same.
- **Single images.** Each image is fitted alone and compared with the joint fit. Where
  they differ by more than twice their combined standard deviation (the single image's
  Laplace ±, the joint fit's image-cluster ±), the result says why, from what the image
  shows: the model does not reproduce it (a mismatch: its ± is conditional on a wrong
  model), or the light is degenerate for that parameter (it grazes the sphere, its
  highlight is saturated or outside the visible sphere, or smoothness and metalness trade
  off in that image).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from ..capture._samples import CaptureSamples
from ..models.reflectance import reflectance_model
from ..precision import float64
from .capture import HELD, CaptureFit, CaptureFitOptions, _terms, fit_capture_samples
from .capture_equivalence import DEFAULT_DELTA_E, capture_equivalence, within


def compared(model: str) -> tuple[str, ...]:
    """The parameters compared for ``model``: its non-linear scalar parameters that a
    capture fits (Strauss s and m, a Phong lobe's exponent, Cook–Torrance's roughness;
    nothing for Lambert): the ones that shape the image, where the linear ones only scale it."""
    reflectance = reflectance_model(model)
    return tuple(
        p.name for p in reflectance.parameters if p.name in reflectance.nonlinear and p.size == 1 and p.name not in HELD
    )


#: Below this share of the sphere lit, a light grazes it.
GRAZING_SHARE = 0.25
#: Above this share of the highlight's pixels saturated, the highlight is not seen.
CLIPPED_SHARE = 0.5
#: |correlation| above which two parameters trade off within one image.
TRADE_OFF = 0.95


def halves(
    samples: CaptureSamples,
    options: CaptureFitOptions,
    *,
    delta_e: float = DEFAULT_DELTA_E,
    progress: Callable[[str], Any] | None = None,
) -> dict[str, Any]:
    """Fit the odd and the even images apart and check that each half's values lie within
    the other's equivalence ranges (see the module docstring)."""
    log = progress or (lambda message: None)
    parts = []
    for name, indices in (("odd", range(0, samples.count, 2)), ("even", range(1, samples.count, 2))):
        part = samples.select(list(indices))
        log(f"stability: fitting the {name} half ({part.count} images)")
        fit = fit_capture_samples(part, options)
        log(f"stability: equivalence ranges of the {name} half")
        ranges = capture_equivalence(part, fit, delta_e=delta_e)
        parts.append(
            {
                "half": name,
                "images": [samples.files[i] for i in indices],
                "values": {k: v for k, v in fit.values().items() if k in ranges},
                "equivalence": ranges,
            }
        )
    agree: dict[str, bool] = {}
    for name in compared(options.model):
        a, b = parts[0], parts[1]
        agree[name] = within(a["values"][name], b["equivalence"][name]) and within(
            b["values"][name], a["equivalence"][name]
        )
    return {
        "halves": parts,
        "delta_e": delta_e,
        "agree": agree,
        "stable": all(agree.values()),
        "meaning": "each half's value lies within the other half's perceptual equivalence range: the two halves of "
        "the lights describe materials that look the same",
    }


def _degenerate(samples: CaptureSamples, i: int, fit: CaptureFit, names: tuple[str, ...]) -> list[str]:
    """What makes image ``i`` a poor witness of the parameters ``names``."""
    reasons = []
    with float64():
        terms = _terms(samples.select([i]))
    cos_alpha = np.asarray(terms["cos_alpha"])[0].max(axis=0)  # (P,)
    cos_beta = np.asarray(terms["cos_beta"])[0].max(axis=0)
    lit = cos_alpha > 0
    share = float(np.mean(lit))
    if share < GRAZING_SHARE:
        reasons.append(f"the light grazes the sphere: {100 * share:.0f} % of it is lit")
    highlight = lit & (cos_beta > 0.95)
    if not highlight.any():
        reasons.append("the highlight falls outside the visible sphere")
    else:
        clipped = float(np.mean(~samples.usable[i][highlight].all(axis=-1)))
        if clipped > CLIPPED_SHARE:
            reasons.append(f"the highlight is saturated ({100 * clipped:.0f} % of its pixels left out)")
    labels = fit.labels
    if "smoothness" in labels and "metalness" in labels:
        a, b = labels.index("smoothness"), labels.index("metalness")
        denom = math.sqrt(max(fit.laplace[a, a] * fit.laplace[b, b], 0.0))
        if denom > 0 and abs(fit.laplace[a, b] / denom) > TRADE_OFF:
            reasons.append(
                f"smoothness and metalness trade off in this image (correlation {fit.laplace[a, b] / denom:+.2f})"
            )
    return reasons


def single_images(
    samples: CaptureSamples,
    joint: CaptureFit,
    options: CaptureFitOptions,
    *,
    verdict: Callable[[CaptureSamples, CaptureFit], str],
    progress: Callable[[str], Any] | None = None,
) -> dict[str, Any]:
    """Fit each image alone and say where, and why, it disagrees with the joint fit ``joint``
    (``verdict`` gives a fit's verdict on its samples)."""
    log = progress or (lambda message: None)
    names = compared(options.model)
    joint_values = joint.values()
    joint_sd = joint.deviations("clustered")
    # one image has one exposure: a per-image exposure is the global one
    alone = replace(options, exposure="global" if options.exposure == "per-image" else options.exposure)
    rows = []
    for i in range(samples.count):
        if i % 8 == 0:
            log(f"stability: image {i + 1} of {samples.count} alone")
        one = samples.select([i])
        row: dict[str, Any] = {"file": samples.files[i]}
        try:
            fit = fit_capture_samples(one, alone)
        except Exception as exc:  # one image that cannot be fitted (all saturated) stops nothing
            row["error"] = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            rows.append(row)
            continue
        values, sd = fit.values(), fit.deviations("laplace")
        row["values"] = {name: values[name] for name in names}
        row["uncertainty_laplace"] = {name: sd[name] for name in names}
        differ = []
        for name in names:
            spread = 2.0 * math.hypot(sd[name], joint_sd[name])
            if abs(values[name] - joint_values[name]) > spread:
                differ.append(name)
        row["disagrees"] = differ
        if differ:
            reasons = []
            own = verdict(one, fit)
            if own == "mismatch":
                reasons.append(
                    f"the {options.model} model does not reproduce this image (mismatch): its ± is conditional on "
                    "a wrong model"
                )
            reasons += _degenerate(samples, i, fit, names)
            row["verdict"] = own
            row["reasons"] = reasons or ["unexplained: the image is reproduced and its light is not degenerate"]
        rows.append(row)
    disagreeing = [r for r in rows if r.get("disagrees")]
    counts: dict[str, int] = {}
    for row in disagreeing:
        for reason in row["reasons"]:
            key = reason.split(":")[0].split(" (")[0]
            counts[key] = counts.get(key, 0) + 1
    return {
        "fits": rows,
        "compared": list(names),
        "disagreeing": len(disagreeing),
        "reasons": counts,
        "rule": "an image disagrees where |single − joint| > 2·√(sd_single² + sd_joint²) (Laplace ± of the single "
        "image, image-cluster ± of the joint fit)",
    }

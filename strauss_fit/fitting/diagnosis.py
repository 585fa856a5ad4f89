r"""Can the model reproduce the target? The verdict of a fit, where it fails and why.

A fit always finds *some* best Strauss material; whether that material reproduces the
target is a separate question, answered against the target's noise
(`strauss_fit.stats.noise.NoiseModel`, which does not come from the fit's own
residual): with σ each value's noise at the fitted radiance,

```text
\chi^2/\mathrm{dof} = \frac{1}{N - P}\sum_i \left(\frac{I_i - T_i}{\sigma_i}\right)^2,
```

whose expected value is 1 with a spread of `\sqrt{2/\mathrm{dof}}` when the model is
right, widened by the noise level's own relative uncertainty ε (`2ε` on χ²/dof). The
verdict is *consistent* when `z = (\chi^2/\mathrm{dof} - 1)/\mathrm{spread} \le 3`,
otherwise *mismatch*.

When the noise is unknown (no sidecar, and `estimate_noise`
cannot separate it from the image's content), the image still bounds it from above: the
local mean square of a second-difference high-pass residual is the noise variance plus the
signal's own curvature (`noise_bound`). The verdict is
then one-sided (`one_sided_verdict`): *mismatch* when the
residual is too large (χ²/dof at the bound above
`BOUND_CHI2`) or too structured (its smooth part alone
above `STRUCTURE_POWER` times the bound's variance, by
`STRUCTURE_Z` standard errors) for any noise up to that
bound, else *undetermined*: a residual within the bound may or may not be noise.

Where: the used pixels fall into regions — the *highlight* of a light (within
`HIGHLIGHT_CORE_DEG` of its mirror direction, and its *wings* out to
`HIGHLIGHT_WING_DEG`), the *rim* (the view grazing the surface, N·V below
`RIM_COS`) and the *body* (the rest) — each with its own χ²/dof and mean signed
residual in noise units (positive: the target is brighter than the fit).

Why, as warnings with stable codes (``docs/formats.md``):

- ``model-mismatch`` — the residual is inconsistent with the noise (or, the noise being
  unknown, with the largest noise the image can hold: the message then says that the
  verdict is one-sided); the message says where, and how visible (CIEDE2000) the
  difference is;
- ``highlight-out-of-reach`` — somewhere the target is brighter than any Strauss material
  can be under the scene's lights (`reachable_maximum`): the lights (or the exposure)
  are stronger than the scene says, or the surface is a physically based metal whose
  highlight concentrates more light than r_s ≤ 1 allows;
- ``color-at-bound`` — a channel of C is pinned at 1: the diffuse term would need more;
- ``highlight-too-narrow`` / ``highlight-too-wide`` — the target's highlight is brighter at
  its core and darker in its wings than the fit (or the reverse): Strauss ties the lobe's
  width and strength to the one smoothness s;
- ``noise-unknown`` — the noise could not be measured and the residual is within the
  largest noise the image can hold, so no verdict: the ± then assume the model is right.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from ..engine import Call, Kernel, Steps, run
from ..models.material import REFLECTION_NAMES
from ..stats.noise import (
    BOUND_CHI2,
    BOUND_TILE,
    STRUCTURE_POWER,
    STRUCTURE_Z,
    NoiseEstimationError,
    NoiseModel,
    OneSidedVerdict,
    noise_bound,
    one_sided_verdict,
)
from .parameters import Layout

#: z of χ²/dof above which the model is said not to reproduce the target.
MISMATCH_Z = 3.0
#: Highlight regions: angle to a light's mirror direction (degrees).
HIGHLIGHT_CORE_DEG = 10.0
HIGHLIGHT_WING_DEG = 25.0
#: Rim: N·V below this (the view within 17° of grazing).
RIM_COS = 0.3
#: A pixel is out of reach when the target exceeds the reachable maximum by this factor
#: plus three noise deviations.
REACH_MARGIN = 1.02
#: Smoothness values of the materials whose brightest values bound what any material can
#: reach: dense towards 1, where the highlight narrows and its peak r_j approaches 1.
_ENVELOPE_SMOOTHNESS = tuple(np.r_[np.linspace(0.0, 0.9, 19), 1 - np.geomspace(0.08, 1e-5, 24), 1.0])


@dataclass
class Diagnosis:
    """The verdict and its evidence (see the module docstring)."""

    verdict: str
    chi2_per_dof: float | None = None
    expected_sd: float | None = None
    z: float | None = None
    per_channel: list[dict[str, float]] = field(default_factory=list)
    regions: dict[str, dict[str, Any]] = field(default_factory=dict)
    warnings: list[dict[str, str]] = field(default_factory=list)
    #: (N,) RMS over channels of the residual in noise units at the used pixels (NaN
    #: when the noise is unknown), for the map in the comparison image.
    standardized: np.ndarray | None = None
    #: The noise being unknown: the bound the image sets on it, (3,) per channel (the
    #: RMS over the used pixels of the local bound), how it was computed, and the
    #: one-sided test against it (None when the noise is known or cannot be bounded).
    noise_bound: np.ndarray | None = None
    noise_bound_method: str | None = None
    one_sided: OneSidedVerdict | None = None

    def warn(self, code: str, message: str) -> None:
        self.warnings.append({"code": code, "message": message})

    def bound_keys(self) -> dict[str, Any]:
        """The result's ``residual`` keys of the one-sided verdict (docs/formats.md):
        ``noise_bound``, ``chi2_per_dof_at_bound`` and ``one_sided``, all None when the
        noise is known (or could not be bounded)."""
        test = self.one_sided
        if test is None or self.noise_bound is None:
            return {"noise_bound": None, "chi2_per_dof_at_bound": None, "one_sided": None}
        return {
            "noise_bound": [float(v) for v in self.noise_bound],
            "chi2_per_dof_at_bound": test.chi2_dof,
            "one_sided": {
                "method": self.noise_bound_method,
                "per_channel": list(test.per_channel),
                "worst_tile": test.worst_tile,
                "lag1_correlation": test.lag1_correlation,
                "structured_power": test.structured_power,
                "structure_z": test.structure_z,
                "pairs": test.pairs,
                "too_large": test.too_large,
                "too_structured": test.too_structured,
                "thresholds": {
                    "chi2_per_dof": BOUND_CHI2,
                    "tile": BOUND_TILE,
                    "structured_power": STRUCTURE_POWER,
                    "structure_z": STRUCTURE_Z,
                },
            },
        }


def chi2_statistics(z2: np.ndarray, parameters: int, relative_stderr: np.ndarray) -> tuple[float, int, float, float]:
    """χ²/dof of squared noise-scaled residuals ``z2`` (N, C), its degrees of freedom, its
    expected spread √(2/dof) widened by the noise level's relative uncertainty ε (per
    channel, each carrying 1/C of χ²: 2·√Σε²/C) and z = (χ²/dof − 1)/spread."""
    dof = max(z2.size - parameters, 1)
    chi2 = float(np.sum(z2) / dof)
    eps = np.asarray(relative_stderr, dtype=float)
    spread = math.sqrt(2.0 / dof + (2.0 * float(np.sqrt(np.sum(eps**2))) / z2.shape[1]) ** 2)
    return chi2, dof, spread, (chi2 - 1.0) / spread


def _brightest(problem: Any, xs: Array) -> Array:
    return jnp.max(jax.vmap(problem.render_physical)(xs), axis=0)


#: The brightest model value at each pixel over a set of materials (a Kernel).
brightest = Kernel(_brightest, "brightest")


def reachable_maximum(problem: Any) -> np.ndarray:
    """`reachable_maximum_steps`, run directly."""
    return run(reachable_maximum_steps(problem))


def reachable_maximum_steps(problem: Any) -> Steps:
    """(N, 3): at each used pixel, the brightest value any Strauss material reaches under
    the problem's lights (their fixed intensities, and a held exposure): the maximum over
    white opaque materials (C = 1, t = 0) of every smoothness, plastic and metal. Brighter
    colours do not exist (C ≤ 1) and every term grows with C; transparency only trades
    reflected light for what is seen through the sphere: where the scene traces
    transmission, the brightest background radiance is added."""
    rows = [[1.0, 1.0, 1.0, s, m, 0.0] for s in _ENVELOPE_SMOOTHNESS for m in (0.0, 1.0)]
    maximum = np.asarray((yield brightest.call(_white_probe(problem), np.asarray(rows))))
    if problem.plan.transmit:
        # light through a transparent sphere is the background's, weighted by at most 1
        # and added to what the surface reflects: bounded by the brightest background
        seen = [problem.prepared.miss_radiance, problem.prepared.reflected_radiance]
        maximum = maximum + max(float(np.max(np.asarray(v))) for v in seen if v is not None)
    return maximum


def reachable_floor_call(problem: Any) -> Call:
    """The kernel call whose result is (N, 3): what a white matte plastic (C = 1,
    s = m = t = 0) reflects at each used pixel — a value some Strauss material reaches, so a
    floor of `reachable_maximum_steps`'s maximum, for one render instead of its 88. A call
    rather than steps: the fit yields it early and reads its result (``np.asarray``) later,
    doing other work while it runs."""
    return brightest.call(_white_probe(problem), np.asarray([[1.0, 1.0, 1.0, 0.0, 0.0, 0.0]]))


def _white_probe(problem: Any) -> Any:
    """``problem`` with the reflection parameters (C, s, m, t) as its only, free, values."""
    layout = Layout(REFLECTION_NAMES)
    return dataclasses.replace(
        problem, layout=layout, pinned=np.zeros(layout.size, dtype=bool), pinned_values=np.zeros(layout.size)
    )


def pixel_regions(prepared: Any) -> dict[str, np.ndarray]:
    """Boolean masks (N,) of the used pixels of a prepared scene: the highlight (core), its
    wings, the rim and the body (see the module docstring)."""
    normal, to_eye = np.asarray(prepared.normal), np.asarray(prepared.to_eye)
    # the components added as columns: the same sum as np.sum(axis=-1), ten times sooner
    cos_view = normal[..., 0] * to_eye[..., 0] + normal[..., 1] * to_eye[..., 1] + normal[..., 2] * to_eye[..., 2]
    count = cos_view.shape[0]
    core = np.zeros(count, dtype=bool)
    wings = np.zeros(count, dtype=bool)
    if prepared.direct is not None:
        lit = np.asarray(prepared.direct.lit)
        cos_beta = np.where(lit, np.asarray(prepared.direct.cos_beta), 0.0).reshape(count, -1)
        nearest = np.max(cos_beta, axis=-1)
        core = nearest > math.cos(math.radians(HIGHLIGHT_CORE_DEG))
        wings = ~core & (nearest > math.cos(math.radians(HIGHLIGHT_WING_DEG)))
    rim = (cos_view < RIM_COS) & ~core & ~wings
    return {"highlight": core, "highlight wings": wings, "rim": rim, "body": ~(core | wings | rim)}


def _region_statistics(
    regions: dict[str, np.ndarray], z: np.ndarray, per_pixel: np.ndarray, total: float
) -> dict[str, dict[str, Any]]:
    """Each non-empty region's pixels, χ²/dof (the mean of z² over its values), share of
    the whole χ² ``total`` and mean z per channel, from the standardized residuals ``z``
    (N, 3) and their per-pixel sums of squares ``per_pixel`` (N,). As sums over a
    membership matrix (regions × pixels) rather than one boolean selection per region and
    statistic (12 copies of the selected values: 3.6 of a 256² fit's 6.7 ms of verdict)."""
    names = [name for name, mask in regions.items() if mask.any()]
    if not names:
        return {}
    membership = np.stack([regions[name] for name in names])
    pixels = membership.sum(axis=1)
    if np.isfinite(per_pixel).all():
        weights = membership.astype(z.dtype)
        sums = weights @ per_pixel
        mean_z = (weights @ z) / pixels[:, None]
    else:  # 0 × inf is NaN in a product: a non-finite value stays in its own regions
        sums = np.array([np.sum(per_pixel[mask]) for mask in membership])
        mean_z = np.array([np.mean(z[mask], axis=0) for mask in membership])
    return {
        name: {
            "pixels": int(pixels[k]),
            "chi2_per_dof": float(sums[k] / (pixels[k] * z.shape[-1])),
            "share_of_chi2": float(sums[k] / total) if total > 0 else 0.0,
            "mean_z": mean_z[k].round(4).tolist(),
        }
        for k, name in enumerate(names)
    }


def diagnose(
    problem: Any,
    model: np.ndarray,
    noise: NoiseModel,
    *,
    parameters: int,
    delta_e_mean: float,
    at_bound: list[str],
    reach: np.ndarray | None,
    image: np.ndarray | None = None,
    index: np.ndarray | None = None,
    sigma: np.ndarray | None = None,
) -> Diagnosis:
    """The verdict for the fitted radiance ``model`` (N, 3) at the used pixels of
    ``problem`` (whose ``target`` it is compared with), ``parameters`` fitted values,
    the fit's mean CIEDE2000, the labels the fit pinned on a bound, and ``reach`` (N, 3),
    the `reachable_maximum` (None when lights or exposure were fitted: then any
    brightness is reachable). ``image`` (H, W, 3), the whole target, and ``index`` (N,),
    the flat indices of the used pixels in it (the rows of ``model``), let an unknown
    noise be bounded from the image for a one-sided verdict (`_one_sided`);
    without them the verdict on such a target stays undetermined. ``sigma`` (N, 3): the
    noise's σ at ``model`` when already computed (``noise.sigma_at(model)``)."""
    target = problem.real(problem.target)
    regions = {name: problem.real(mask) for name, mask in pixel_regions(problem.prepared).items()}
    diagnosis = Diagnosis("undetermined")
    color_at_one = [label[-1] for label in at_bound if label.startswith("color_") and label.endswith(("r", "g", "b"))]
    color_at_one = [c for c in color_at_one if _pinned_at_one(problem, "color_" + c)]
    if not noise.known:
        sigma = None  # the bound's, when the image gives one
        if image is not None and index is not None:
            # σ ≤ the bound: the out-of-reach check below may use it as its margin
            sigma = _one_sided(diagnosis, target, model, noise, parameters, image, index, regions, delta_e_mean)
        if diagnosis.verdict != "mismatch":
            test = diagnosis.one_sided
            within = (
                ""
                if test is None
                else f"the residual is within the largest noise the image can hold (χ²/dof {test.chi2_dof:.3g} at "
                f"that level, structured power {test.structured_power:.2g}), so "
            )
            diagnosis.warn(
                "noise-unknown",
                "the target's noise could not be measured ("
                + "; ".join(noise.notes)
                + f"): {within}no verdict on whether the model reproduces the target, and the ± assume it does; "
                "give the noise level (--noise)",
            )
    else:
        sigma = noise.sigma_at(model) if sigma is None else sigma
        z = (target - model) / sigma
        z2 = z**2
        chi2, dof, spread, zscore = chi2_statistics(z2, parameters, noise.relative_stderr)
        diagnosis.chi2_per_dof, diagnosis.expected_sd, diagnosis.z = chi2, spread, zscore
        per_pixel = z2[:, 0] + z2[:, 1] + z2[:, 2]  # as z2.sum(axis=-1), ten times sooner
        diagnosis.standardized = np.sqrt(per_pixel / z2.shape[-1])
        diagnosis.per_channel = [
            {"channel": c, "chi2_per_dof": float(np.sum(z2[:, i]) / max(z2.shape[0] - parameters / 3, 1))}
            for i, c in enumerate("rgb")
        ]
        total = float(np.sum(per_pixel))
        diagnosis.regions.update(_region_statistics(regions, z, per_pixel, total))
        diagnosis.verdict = "mismatch" if zscore > MISMATCH_Z else "consistent"
        if diagnosis.verdict == "mismatch":
            diagnosis.warn("model-mismatch", _mismatch_message(diagnosis, regions, delta_e_mean))
            _lobe_shape(diagnosis)
    if reach is not None:
        _out_of_reach(diagnosis, target, reach, sigma)
    if color_at_one:
        names = ", ".join({"r": "red", "g": "green", "b": "blue"}[c] for c in color_at_one)
        diagnosis.warn(
            "color-at-bound",
            f"C is pinned at 1 in the {names} channel{'s' if len(color_at_one) > 1 else ''}: the target is brighter "
            "there than a white Strauss surface under the scene's lights, so the colour cannot follow it; the lights "
            "or the exposure are probably stronger than the scene says (try --fit-exposure)",
        )
    return diagnosis


def _one_sided(
    diagnosis: Diagnosis,
    target: np.ndarray,
    model: np.ndarray,
    noise: NoiseModel,
    parameters: int,
    image: np.ndarray,
    index: np.ndarray,
    regions: dict[str, np.ndarray],
    delta_e_mean: float,
) -> np.ndarray | None:
    """The one-sided verdict of a target whose noise is unknown: the residual against the
    largest noise the image can hold (`noise_bound`,
    `one_sided_verdict`). Sets ``diagnosis``'s bound
    and test, and on a mismatch its verdict and a ``model-mismatch`` warning that says the
    verdict is one-sided. Returns the bound σ_b (N, 3) at the used pixels; None, with
    nothing set, when the used pixels are too few to bound the noise (the verdict stays
    undetermined)."""
    pixels = np.asarray(image, dtype=np.float64)
    height, width = pixels.shape[:2]
    index = np.asarray(index)
    used = np.zeros(height * width, dtype=bool)
    used[index] = True
    used = used.reshape(height, width)
    try:
        bound = noise_bound(pixels, used, storage=noise.storage, quantised=noise.quantised)
    except NoiseEstimationError:
        return None
    residual = np.zeros(pixels.shape)
    residual.reshape(-1, pixels.shape[-1])[index] = target - model  # positive: the target is brighter
    test = one_sided_verdict(residual, bound, parameters)
    diagnosis.noise_bound, diagnosis.noise_bound_method, diagnosis.one_sided = bound.sigma, bound.method, test
    sigma = bound.at(index)
    if test.mismatch:
        diagnosis.verdict = "mismatch"
        z2 = np.sum(((target - model) / sigma) ** 2, axis=-1)  # per used pixel, in bound units
        diagnosis.warn("model-mismatch", _one_sided_message(test, bound.sigma, z2, regions, delta_e_mean))
    return sigma


def _one_sided_message(
    test: OneSidedVerdict,
    bound: np.ndarray,
    z2: np.ndarray,
    regions: dict[str, np.ndarray],
    delta_e_mean: float,
) -> str:
    """The ``model-mismatch`` message of a one-sided verdict: which test fired and by how
    much, in units of the bound ``bound`` (3,); where the residual concentrates (``z2``,
    (N,): Σ_c (r/σ_b)² per used pixel, over the ``regions``); how visible it is."""
    reasons = []
    tile = test.worst_tile
    if test.too_large and test.chi2_dof > BOUND_CHI2:
        reasons.append(
            f"too large: {math.sqrt(max(test.chi2_dof, 0.0)):.3g} times that level (χ²/dof {test.chi2_dof:.4g} at it, "
            f"where the test allows {BOUND_CHI2:g})"
        )
    elif test.too_large and tile is not None:  # only a tile is beyond: a misfit confined to a region
        reasons.append(
            f"too large in the {tile['size']}×{tile['size']} pixels from row {tile['row']}, column {tile['column']}: "
            f"{math.sqrt(max(tile['chi2_per_dof'], 0.0)):.3g} times that level there (its mean square is "
            f"{tile['chi2_per_dof']:.4g} times that level's variance, where the test allows {BOUND_CHI2:g}; "
            f"{test.chi2_dof:.3g} over the sphere)"
        )
    if test.too_structured:
        reasons.append(
            f"too structured: its smooth part alone holds {test.structured_power:.3g} times that level's variance "
            f"(neighbouring pixels agree, ρ₁ = {test.lag1_correlation:.2f}, {test.structure_z:.3g} standard errors "
            "above the 0 of noise independent between pixels)"
        )
    total, count = float(np.sum(z2)), sum(int(mask.sum()) for mask in regions.values())
    location = ""
    if total > 0 and count > 0:
        ratio, name, share, pixels = max(
            (float(np.sum(z2[mask])) / total / (mask.sum() / count), name, float(np.sum(z2[mask])) / total, mask.sum())
            for name, mask in regions.items()
            if mask.any()
        )
        if ratio > 1.5:  # as for the two-sided verdict: a region that holds clearly more than its share
            location = (
                f"; it concentrates in the {name} ({100 * share:.0f} % of χ² at the bound on "
                f"{100 * pixels / count:.0f} % of the pixels)"
            )
    visible = (
        "below one just-noticeable difference, so the fit still looks right"
        if delta_e_mean < 1
        else "a visible difference"
    )
    levels = ", ".join(f"{v:.2g}" for v in bound)
    return (
        "the Strauss model cannot reproduce this target — a one-sided verdict: the target's noise is unknown, "
        f"but even at the largest level the image can hold (RMS {levels} per channel, bounded by its "
        f"high-frequency content) the residual is {' and '.join(reasons)}{location}; "
        f"mean CIEDE2000 {delta_e_mean:.2g}, {visible}"
    )


def _pinned_at_one(problem: Any, label: str) -> bool:
    """Whether the entry ``label`` is pinned at 1 (not at 0: a channel at 0 is a colour
    without that primary, not a bound the target pushes against)."""
    index = problem.layout.labels().index(label)
    return bool(np.asarray(problem.pinned)[index]) and float(np.asarray(problem.pinned_values)[index]) >= 1.0


def _mismatch_message(diagnosis: Diagnosis, regions: dict[str, np.ndarray], delta_e_mean: float) -> str:
    ratio = math.sqrt(max(diagnosis.chi2_per_dof or 0.0, 0.0))
    where = sorted(
        (
            (info["share_of_chi2"] / max(info["pixels"] / sum(r.sum() for r in regions.values()), 1e-12), name, info)
            for name, info in diagnosis.regions.items()
        ),
        key=lambda item: -item[0],
    )
    worst = where[0] if where else None
    location = ""
    if worst is not None and worst[0] > 1.5:
        _, name, info = worst
        location = (
            f"; it concentrates in the {name} ({100 * info['share_of_chi2']:.0f} % of χ² on "
            f"{100 * info['pixels'] / sum(r.sum() for r in regions.values()):.0f} % of the pixels)"
        )
    visible = (
        "below one just-noticeable difference, so the fit still looks right"
        if delta_e_mean < 1
        else "a visible difference"
    )
    return (
        f"the Strauss model cannot reproduce this target: the residual is {ratio:.3g} times the noise "
        f"(χ²/dof {diagnosis.chi2_per_dof:.4g}, expected 1 ± {diagnosis.expected_sd:.2g}){location}; "
        f"mean CIEDE2000 {delta_e_mean:.2g}, {visible}"
    )


def _lobe_shape(diagnosis: Diagnosis) -> None:
    core, wings = diagnosis.regions.get("highlight"), diagnosis.regions.get("highlight wings")
    if core is None or wings is None:
        return
    core_z, wing_z = float(np.mean(core["mean_z"])), float(np.mean(wings["mean_z"]))
    if core_z > 2 and wing_z < -1:
        diagnosis.warn(
            "highlight-too-narrow",
            f"the target's highlight is brighter at its core (mean residual +{core_z:.2g} σ) and darker in its "
            f"wings ({wing_z:.2g} σ) than the fit: it is narrower for its strength than a Strauss lobe, whose "
            "width and peak are both set by the one smoothness s",
        )
    elif core_z < -2 and wing_z > 1:
        diagnosis.warn(
            "highlight-too-wide",
            f"the target's highlight is dimmer at its core ({core_z:.2g} σ) and brighter in its wings "
            f"(+{wing_z:.2g} σ) than the fit: it is wider for its strength than a Strauss lobe, whose width "
            "and peak are both set by the one smoothness s",
        )


def _out_of_reach(diagnosis: Diagnosis, target: np.ndarray, reach: np.ndarray, sigma: np.ndarray | None) -> None:
    margin = 0.0 if sigma is None else 3.0 * np.nan_to_num(sigma)
    beyond = target > reach * REACH_MARGIN + margin
    if not beyond.any():
        return
    pixels = int(np.any(beyond, axis=-1).sum())
    ratio = target / np.maximum(reach, 1e-300)
    worst = np.unravel_index(np.argmax(np.where(beyond, ratio, 0.0)), ratio.shape)
    diagnosis.warn(
        "highlight-out-of-reach",
        f"{pixels} pixel(s) of the target are brighter than any Strauss material can be under the scene's lights "
        f"(up to {ratio[worst]:.3g} times the brightest reachable value, {target[worst]:.4g} against "
        f"{reach[worst]:.4g}): the lights or the exposure are stronger than the scene says (try --fit-exposure "
        "or --fit-lights), or the surface concentrates more light into its highlight than r_s ≤ 1 allows "
        "(a physically based metal)",
    )


#: Correlations above this between free parameters are said in the table.
STRONG_CORRELATION = 0.95
#: A parameter whose deviation exceeds this fraction of its scale is "barely constrained"
#: (the identifiability analysis's threshold).
WEAK_FRACTION = 0.05


def uncertainty_warnings(
    layout: Layout,
    covariance: np.ndarray,
    x: np.ndarray,
    pinned: np.ndarray,
    free_covariance: np.ndarray | None,
    equivalence: dict[str, Any] | None = None,
) -> list[dict[str, str]]:
    """What the ± alone would hide, as warnings for the table and the report:

    - ``strong-correlation``: two free entries correlate beyond `STRONG_CORRELATION`
      (the image pins their combination, not each);
    - ``weakly-constrained``: a free entry's deviation exceeds `WEAK_FRACTION` of its
      scale (`deviation_scale`);
    - ``flat-at-bound``: an entry pinned at a bound (deviation 0 there) whose deviation,
      were it free (``free_covariance``: the same covariance with nothing pinned), would
      exceed that fraction: the cost is nearly flat, and the bound, not the image, sets it.

    ``equivalence`` (`strauss_fit.fitting.equivalence.equivalence_ranges`), when
    computed, is quoted."""
    from .identifiability import deviation_scale

    labels = layout.labels()
    owner = [name for name, size in zip(layout.names, layout.sizes) for _ in range(size)]
    channel = {f"color_{c}": i for i, c in enumerate("rgb")}
    sd = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    scale = np.array([float(deviation_scale(n, v)) for n, v in zip(owner, x)])

    def seen(k: int) -> str:
        if not equivalence or owner[k] not in equivalence:
            return ""
        pair = equivalence[owner[k]]
        low, high = pair[channel[labels[k]]] if labels[k] in channel else pair
        return f"; it looks the same (mean CIEDE2000 within the threshold) from {low:.3g} to {high:.3g}"

    out: list[dict[str, str]] = []
    free = ~np.asarray(pinned, dtype=bool)
    norm = np.outer(sd, sd)
    corr = np.divide(covariance, norm, out=np.zeros_like(covariance), where=norm > 0)
    pairs = [
        f"{labels[i]} and {labels[j]} ({corr[i, j]:+.3f})"
        for i in range(len(labels))
        for j in range(i + 1, len(labels))
        if free[i] and free[j] and owner[i] != owner[j] and abs(corr[i, j]) > STRONG_CORRELATION
    ]
    if pairs:
        out.append(
            {
                "code": "strong-correlation",
                "message": f"{'; '.join(pairs)} trade off: the image pins a combination, and each ± holds only "
                "with its partner at its fitted value",
            }
        )
    for k in np.flatnonzero(free & (sd > WEAK_FRACTION * scale)):
        out.append(
            {
                "code": "weakly-constrained",
                "message": f"{labels[k]} is barely constrained (± {sd[k]:.2g}, over {WEAK_FRACTION:.0%} of its "
                f"scale){seen(k)}",
            }
        )
    if free_covariance is not None:
        loose = np.sqrt(np.maximum(np.diag(free_covariance), 0.0))
        for k in np.flatnonzero(~free & (loose > WEAK_FRACTION * scale)):
            out.append(
                {
                    "code": "flat-at-bound",
                    "message": f"{labels[k]} sits on its bound {x[k]:.3g} with deviation 0 there, but the cost is "
                    f"nearly flat (free, it would be ± {loose[k]:.2g}): the bound, not the image, sets it{seen(k)}",
                }
            )
    return out

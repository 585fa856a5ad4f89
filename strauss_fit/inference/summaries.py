r"""Summaries of uncertainty, the fit's ± against the emcee posterior, and degeneracy
warnings in plain language. Pure NumPy, no plotting (`strauss_fit.reporting.fit_report` draws).

Percentiles: the posterior median and the central 68 % (16th–84th percentile) and 95 %
(2.5th–97.5th) intervals of the samples after burn-in.

Comparison (per parameter, when a chain and the fit's ± both exist; the ± is the noise
sandwich or the Laplace estimate, as the fit computed it, and the notes name it). With
`\hat\theta` and `s_L` the optimum and the fit's deviation, and
`m, q_{16}, q_{84}` the posterior median and percentiles, `s_P = (q_{84}-q_{16})/2`:

- *width*: disagree if `s_P / s_L \notin [0.8, 1.25]`;
- *shift*: disagree if `|m - \hat\theta| > 0.5\, s_P`;
- a width or shift is blamed on a parameter the fit pinned on a bound when the two
  correlate (|ρ| > 0.5) in the posterior: the fit's ± holds it fixed, the posterior does
  not; otherwise on the model's non-linearity;
- *skew*: disagree if the tails differ, `|u - d|/(u + d) > 0.2` with
  `u = q_{84} - m`, `d = m - q_{16}`;
- *bound*: the prior bound lies within `2 s_P` of the median (the posterior is cut
  there and a symmetric ± is misleading) — the note then gives a one-sided 95 % limit;
- *banana*: for a pair of parameters, regressing one standardised sample on the other
  with a quadratic term explains at least 0.05 more of its variance than the straight
  line (a curved ridge, which no covariance matrix describes).

Degeneracies: a pair of quantities with `|\rho| > 0.9` trades off; it is called
inseparable when `|\rho| > 0.99` or either deviation exceeds 5 % of its scale, and a
strong correlation otherwise. Besides the
parameters, the *brightness of C* (the mean of the three colour channels) is considered,
because that is what transparency, metalness and light intensities trade with. Parameters
the fit held fixed (with its reason) are listed too.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..fitting.identifiability import deviation_scale
from ..fitting.result import FitResult
from ..stats import laplace as _laplace
from .adjustment import loss_of

if TYPE_CHECKING:
    from .sampler import Chain

#: |correlation| above which two quantities are reported as trading off.
DEGENERACY_THRESHOLD = 0.9
#: Above this |correlation|, or when a deviation exceeds LOOSE_SD of the parameter's scale,
#: the scene is said not to separate the two at all.
SEVERE_CORRELATION = 0.99
LOOSE_SD = 0.05
WIDTH_RATIO_RANGE = (0.8, 1.25)
SHIFT_LIMIT = 0.5
SKEW_LIMIT = 0.2
BOUND_SDS = 2.0
BANANA_GAIN = 0.05
#: A parameter pinned on a bound by the fit explains another's disagreement above this |correlation|.
PINNED_PARTNER = 0.5
PERCENTILES = (2.5, 16.0, 50.0, 84.0, 97.5)
BRIGHTNESS = "brightness of C"

_CHANNEL = {"r": "red", "g": "green", "b": "blue"}
_NAMES = {
    "smoothness": "s (smoothness)",
    "metalness": "m (metalness)",
    "transparency": "t (transparency)",
    "ior": "n (index of refraction)",
    BRIGHTNESS: "the brightness of C",
}


def describe(label: str) -> str:
    """A label in words: ``color_r`` → "the red channel of C", ``smoothness`` → "s (smoothness)"."""
    if label.startswith("color_") and label[-1] in _CHANNEL:
        return f"the {_CHANNEL[label[-1]]} channel of C"
    if label in _NAMES:
        return _NAMES[label]
    return label.replace("_", " ")


def posterior_summary(samples: np.ndarray, labels: Sequence[str]) -> dict[str, Any]:
    """Mean, standard deviation, median and the 2.5/16/84/97.5 percentiles per label, and
    the correlation matrix, of samples (n, P)."""
    samples = np.asarray(samples, dtype=np.float64)
    q = np.percentile(samples, PERCENTILES, axis=0)
    sd = samples.std(axis=0, ddof=1)
    corr = np.corrcoef(samples, rowvar=False) if samples.shape[1] > 1 else np.ones((1, 1))
    corr = np.nan_to_num(np.atleast_2d(corr))
    out: dict[str, Any] = {"labels": list(labels), "count": int(samples.shape[0]), "parameters": {}}
    for k, label in enumerate(labels):
        out["parameters"][label] = {
            "mean": float(samples[:, k].mean()),
            "sd": float(sd[k]),
            "median": float(q[2, k]),
            "p2.5": float(q[0, k]),
            "p16": float(q[1, k]),
            "p84": float(q[3, k]),
            "p97.5": float(q[4, k]),
        }
    out["correlation"] = np.round(corr, 6).tolist()
    return out


#: What `Laplace` calls the fit's ± in words, by ``uncertainty_method.name``.
SANDWICH = "noise sandwich"
LAPLACE = "Laplace estimate"


@dataclass
class Laplace:
    """The fit's Gaussian uncertainty per vector entry: optimum, deviation (0 where the fit
    pinned the entry at a bound) and correlation matrix; ``method`` names it in words
    (`SANDWICH` or `LAPLACE`, as the fit computed its ±), so that notes about it
    say which interval they mean. The class keeps its old name: it began as the Laplace
    estimate only."""

    labels: list[str]
    x_hat: np.ndarray
    sd: np.ndarray
    correlation: np.ndarray
    at_bound: list[str] = field(default_factory=list)
    method: str = LAPLACE

    @property
    def covariance(self) -> np.ndarray:
        return self.correlation * np.outer(self.sd, self.sd)

    @classmethod
    def from_fit(cls, fit: FitResult | dict[str, Any]) -> Laplace:
        """From a fit result's ``free``, values, ``uncertainty`` and ``correlation`` (a
        `FitResult` or its JSON)."""
        fit = FitResult.from_json(fit)
        labels, values, sds = [], [], []
        for name in fit.free:
            value = fit.value(name)
            sd = fit.uncertainty.get(name, 0.0)
            if isinstance(value, list):
                labels += [f"{name}_{c}" for c in "rgb"]
                values += list(value)
                sds += list(sd) if isinstance(sd, list) else [sd] * 3
            else:
                labels.append(name)
                values.append(value)
                sds.append(sd)
        corr = fit.correlation
        matrix = np.asarray(corr.get("matrix", np.eye(len(labels))), dtype=np.float64)
        if corr.get("labels", labels) != labels or matrix.shape != (len(labels), len(labels)):
            matrix = np.eye(len(labels))
        method = SANDWICH if (fit.uncertainty_method or {}).get("name") == "noise sandwich" else LAPLACE
        return cls(
            labels,
            np.asarray(values, dtype=np.float64),
            np.asarray(sds, dtype=np.float64),
            matrix,
            fit.at_bound,
            method,
        )


def with_brightness(labels: Sequence[str], covariance: np.ndarray) -> tuple[list[str], np.ndarray]:
    """Add the brightness of C, (r + g + b)/3, as a derived quantity: Σ' = A Σ Aᵀ."""
    labels = list(labels)
    channels = [labels.index(f"color_{c}") for c in "rgb" if f"color_{c}" in labels]
    if len(channels) != 3:
        return labels, covariance
    a = np.vstack([np.eye(len(labels)), np.zeros((1, len(labels)))])
    a[-1, channels] = 1 / 3
    return labels + [BRIGHTNESS], a @ covariance @ a.T


def _is_channel(label: str) -> bool:
    return label.startswith("color_")


def degeneracy_warnings(
    labels: Sequence[str],
    covariance: np.ndarray,
    held: dict[str, Any] | None = None,
    threshold: float = DEGENERACY_THRESHOLD,
    source: str = "posterior",
    values: Sequence[float] | None = None,
) -> list[str]:
    """Plain-language warnings: pairs with |ρ| > ``threshold`` (the brightness of C
    included), strongest first, then parameters the fit held and why.

    A pair is said to be inseparable when |ρ| > `SEVERE_CORRELATION` or either
    deviation exceeds `LOOSE_SD` of its scale (1 for values in [0, 1], 0.5 for n,
    the value itself for a light intensity, taken from ``values``); otherwise it is
    reported as a strong correlation, with the factor 1/sqrt(1 - ρ²) by which
    knowing the other would shrink each deviation."""
    names, cov = with_brightness(labels, np.asarray(covariance, dtype=np.float64))
    means = list(values) if values is not None else [1.0] * len(labels)
    means = means + [1.0] * (len(names) - len(means))
    corr = _laplace.correlation(cov)
    sd = _laplace.deviations(cov)
    pairs = [
        (abs(corr[i, j]), i, j)
        for i in range(len(names))
        for j in range(i + 1, len(names))
        if abs(corr[i, j]) > threshold
    ]
    # Trade-offs with the brightness of C first: they explain the channel pairs that follow.
    pairs.sort(key=lambda t: (BRIGHTNESS not in (names[t[1]], names[t[2]]), -t[0]))
    warnings, covered = [], set()
    for _, i, j in pairs:
        a, b = names[i], names[j]
        if BRIGHTNESS in (a, b):
            other = b if a == BRIGHTNESS else a
            if _is_channel(other):
                continue  # a channel and the mean it is part of: not a trade-off
            covered.add(other)
        elif covered and ((_is_channel(a) and (b in covered or _is_channel(b))) or (_is_channel(b) and a in covered)):
            continue  # already said through the brightness of C
        rho = corr[i, j]
        loose = max(sd[i] / float(deviation_scale(a, means[i])), sd[j] / float(deviation_scale(b, means[j]))) > LOOSE_SD
        if abs(rho) > SEVERE_CORRELATION or loose:
            how = "raising one while lowering the other" if rho < 0 else "raising both together"
            warnings.append(
                f"{describe(a)} and {describe(b)} trade off (correlation {rho:+.2f} in the {source}): "
                f"{how} leaves the image almost unchanged, so this scene cannot separate them; "
                f"each is known only to ±{sd[i]:.2g} and ±{sd[j]:.2g}."
            )
        else:
            warnings.append(
                f"{describe(a)} and {describe(b)} are strongly correlated ({rho:+.2f} in the {source}): the image "
                f"pins down mainly a combination of them, and each alone is known {1 / np.sqrt(1 - rho**2):.0f} times "
                f"less well (±{sd[i]:.2g} and ±{sd[j]:.2g}) than it would be if the other were known."
            )
    for name, info in (held or {}).items():
        reason = info.get("reason", "") if isinstance(info, dict) else str(info)
        if reason.startswith("fixed by the user") or reason.startswith("held by the user"):
            continue
        value = _fmt(info.get("value") if isinstance(info, dict) else None)
        warnings.append(
            f"{describe(name)} was not fitted: {reason}. It is held at {value}, and every interval "
            "in this report assumes exactly that value."
        )
    return warnings


def _fmt(value: Any) -> str:
    if isinstance(value, (list, tuple)):
        return "(" + ", ".join(f"{float(v):.3g}" for v in value) + ")"
    if value is None:
        return "its scene value"
    return f"{float(value):.3g}"


@dataclass
class ComparisonRow:
    """One parameter's widths from the fit's ± (``laplace_sd``, whichever kind it is) and
    from the posterior, and what disagrees."""

    label: str
    x_hat: float
    laplace_sd: float
    median: float
    posterior_sd: float
    width_ratio: float | None
    shift: float
    skew: float
    issues: list[str]

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def compare(
    laplace: Laplace, summary: dict[str, Any], samples: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> tuple[list[ComparisonRow], list[str]]:
    """Rows per parameter and plain-language notes where the fit's ± (named by
    ``laplace.method``) and the posterior disagree (the rules of the module docstring)."""
    rows, notes = [], []
    name = laplace.method
    corr = np.asarray(summary["correlation"], dtype=np.float64)
    pinned = [j for j, label in enumerate(laplace.labels) if label in laplace.at_bound or laplace.sd[j] == 0]

    def cause(k: int) -> str:
        """Why the widths or centres differ: a pinned partner if there is one."""
        partners = [(abs(corr[k, j]), j) for j in pinned if j != k and abs(corr[k, j]) > PINNED_PARTNER]
        if not partners:
            return "the model is not linear over the uncertainty, so trust the posterior"
        _, j = max(partners)
        return (
            f"the {name} holds {describe(laplace.labels[j])} fixed on its bound, while the posterior "
            f"lets it move inward and this parameter moves with it (correlation {corr[k, j]:+.2f}); "
            "trust the posterior"
        )

    for k, label in enumerate(laplace.labels):
        p = summary["parameters"][label]
        s_post = (p["p84"] - p["p16"]) / 2
        s_lap = float(laplace.sd[k])
        up, down = p["p84"] - p["median"], p["median"] - p["p16"]
        skew = (up - down) / (up + down) if up + down > 0 else 0.0
        shift = (p["median"] - laplace.x_hat[k]) / s_post if s_post > 0 else 0.0
        ratio = s_post / s_lap if s_lap > 0 else None
        issues = []
        word = describe(label)
        near_low = p["median"] - lower[k] < BOUND_SDS * s_post
        near_high = upper[k] - p["median"] < BOUND_SDS * s_post
        if label in laplace.at_bound or s_lap == 0:
            issues.append("bound")
            side, limit = (
                ("upper", p["p97.5"])
                if near_low or laplace.x_hat[k] - lower[k] < upper[k] - laplace.x_hat[k]
                else ("lower", p["p2.5"])
            )
            notes.append(
                f"{word}: the fit put it on its bound ({laplace.x_hat[k]:.4g}), where the {name} "
                f"gives no interval; the posterior is one-sided with a 95 % {side} limit of {limit:.4g}."
            )
        elif near_low or near_high:
            issues.append("bound")
            bound = lower[k] if near_low else upper[k]
            side, limit = ("upper", p["p97.5"]) if near_low else ("lower", p["p2.5"])
            notes.append(
                f"{word}: the posterior runs into the bound {bound:g}, so it is cut off there and the "
                f"symmetric ±{s_lap:.2g} of the {name} misleads; quote the 95 % {side} limit {limit:.4g} instead."
            )
        if ratio is not None and not WIDTH_RATIO_RANGE[0] <= ratio <= WIDTH_RATIO_RANGE[1]:
            issues.append("width")
            notes.append(
                f"{word}: the posterior is {'' if ratio > 1 else 'only '}{ratio:.2f} times as wide as "
                f"the {name} (±{s_post:.2g} against ±{s_lap:.2g}): {cause(k)}."
            )
        if abs(shift) > SHIFT_LIMIT and "bound" not in issues:
            issues.append("shift")
            notes.append(
                f"{word}: the posterior median {p['median']:.4g} lies {abs(shift):.1f} posterior "
                f"standard deviations from the fit's optimum {laplace.x_hat[k]:.4g}"
                + (f": {cause(k)}." if pinned and cause(k).startswith(f"the {name} holds") else ".")
            )
        if abs(skew) > SKEW_LIMIT and "bound" not in issues:
            issues.append("skew")
            notes.append(
                f"{word}: the posterior is skewed (its {'upper' if skew > 0 else 'lower'} tail is "
                f"{max(up, down) / max(min(up, down), 1e-300):.1f} times longer): quote the percentiles, "
                "not a ± value."
            )
        rows.append(
            ComparisonRow(
                label, float(laplace.x_hat[k]), s_lap, p["median"], s_post, ratio, float(shift), float(skew), issues
            )
        )
    for a, b, gain in curved_pairs(samples, laplace.labels):
        notes.append(
            f"{describe(a)} and {describe(b)}: the posterior is curved (banana-shaped; a quadratic "
            f"explains {gain:.0%} more of their relation than a straight line), which the ellipse of the "
            f"{name} cannot describe."
        )
    return rows, notes


def curved_pairs(
    samples: np.ndarray, labels: Sequence[str], limit: int = 20000, gain_threshold: float = BANANA_GAIN
) -> list[tuple[str, str, float]]:
    """Pairs whose joint posterior is curved (see the module docstring), strongest first."""
    samples = np.asarray(samples, dtype=np.float64)
    if samples.shape[0] > limit:
        samples = samples[np.random.default_rng(0).choice(samples.shape[0], limit, replace=False)]
    sd = samples.std(axis=0)
    z = np.divide(samples - samples.mean(axis=0), sd, out=np.zeros_like(samples), where=sd > 0)
    found = []
    for i in range(z.shape[1]):
        for j in range(z.shape[1]):
            if i == j or sd[i] == 0 or sd[j] == 0:
                continue
            x, y = z[:, i], z[:, j]
            r_lin = _r2(np.column_stack([np.ones_like(x), x]), y)
            r_quad = _r2(np.column_stack([np.ones_like(x), x, x * x]), y)
            gain = r_quad - r_lin
            if gain >= gain_threshold:
                found.append((labels[i], labels[j], float(gain)))
    # keep one direction per pair (the stronger)
    best: dict[frozenset, tuple[str, str, float]] = {}
    for a, b, gain in found:
        key = frozenset((a, b))
        if key not in best or gain > best[key][2]:
            best[key] = (a, b, gain)
    return sorted(best.values(), key=lambda t: -t[2])


def _r2(design: np.ndarray, y: np.ndarray) -> float:
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    residual = y - design @ coef
    total = float(np.sum((y - y.mean()) ** 2))
    return 1.0 - float(np.sum(residual**2)) / total if total > 0 else 0.0


# --- a chain against its fit ------------------------------------------------------------------


@dataclass
class ChainPosterior:
    """A chain's posterior set against the fit's ± (its noise sandwich or Laplace
    estimate): the diagnostics, the samples after burn-in (at most ``max_samples`` of them,
    drawn without replacement), the summary (of *all* samples after burn-in), the prior
    box, the comparison rows and notes of `compare`, and the samples' covariance."""

    diagnostics: Any
    samples: np.ndarray
    summary: dict[str, Any]
    lower: np.ndarray
    upper: np.ndarray
    rows: list[ComparisonRow]
    notes: list[str]
    covariance: np.ndarray


def chain_posterior(chain: Chain, laplace: Laplace, max_samples: int | None = None) -> ChainPosterior:
    """Everything the sampler's summary and the report say about a chain (see
    `ChainPosterior`); the labels are the chain's."""
    labels = chain.labels
    diagnostics = chain.diagnostics()
    samples = chain.samples(diagnostics.burn_in)
    if max_samples is not None and samples.shape[0] > max_samples:
        samples = samples[np.random.default_rng(0).choice(samples.shape[0], max_samples, replace=False)]
    summary = posterior_summary(chain.samples(diagnostics.burn_in), labels)
    prior = chain.meta.get("prior", {})
    lower = np.array([prior.get(label, [-np.inf, np.inf])[0] for label in labels], dtype=np.float64)
    upper = np.array([prior.get(label, [-np.inf, np.inf])[1] for label in labels], dtype=np.float64)
    rows, notes = compare(laplace, summary, samples, lower, upper)
    covariance = np.atleast_2d(np.cov(samples, rowvar=False))
    return ChainPosterior(diagnostics, samples, summary, lower, upper, rows, notes, covariance)


def summarise_chain(chain: Chain) -> dict[str, Any]:
    """The summary JSON of a chain (``strauss-fit sample`` writes it beside the chain):
    diagnostics, posterior percentiles, the ± of the fit it started from (its noise
    sandwich or Laplace estimate), their comparison and the warnings."""
    meta = chain.meta
    fit = FitResult.from_json(meta["fit"])
    laplace = Laplace.from_fit(fit)
    posterior = chain_posterior(chain, laplace)
    diagnostics = posterior.diagnostics
    warnings = degeneracy_warnings(chain.labels, posterior.covariance, fit.held, values=laplace.x_hat)
    mismatch = loss_warning(meta["fit"])
    if mismatch:
        warnings.insert(0, mismatch)
    return {
        "uncertainty_method": (fit.uncertainty_method or {}).get("name", "laplace"),
        "fit_verdict": fit.verdict,
        "fit_warnings": [dict(w) for w in fit.warnings if isinstance(w, dict)],
        "adjustment": adjustment_summary(chain, laplace, diagnostics.burn_in),
        "chain": chain.path,
        "target": meta.get("target"),
        "scene": meta.get("scene"),
        "labels": chain.labels,
        "sigma": meta["sigma"],
        "sigma_source": meta.get("sigma_source"),
        "prior": meta["prior"],
        "walkers": diagnostics.walkers,
        "steps": diagnostics.steps,
        "diagnostics": diagnostics.as_dict(),
        "posterior": posterior.summary,
        "laplace": {
            "labels": laplace.labels,
            "x_hat": laplace.x_hat.tolist(),
            "sd": laplace.sd.tolist(),
            "correlation": laplace.correlation.tolist(),
        },
        "comparison": {"rows": [r.as_dict() for r in posterior.rows], "notes": posterior.notes},
        "warnings": warnings,
    }


def loss_warning(fit: FitResult | dict[str, Any]) -> str | None:
    """A warning when the fit a chain is set against minimised another loss than least
    squares (chains written before `strauss_fit.inference.sampler.sample` refused such
    fits, or a report given another fit than its chain's): the chain's likelihood is least
    squares, so it centres elsewhere and the fit's ± is another estimator's spread."""
    data = fit.to_json() if isinstance(fit, FitResult) else fit
    loss = loss_of(data)
    if loss == "linear":
        return None
    return (
        f"the chain's likelihood is least squares, but the fit minimised the {loss} loss: the posterior centres on "
        f"the least-squares optimum, not on the fit's values, and the fit's ± is the spread of the {loss} fit; "
        "compare them only after refitting with --loss linear (and sampling from that fit)"
    )


def adjustment_summary(chain: Chain, laplace: Laplace, discard: int) -> dict[str, Any]:
    """What the chain's adjustment did (`strauss_fit.inference.adjustment`): the
    method and why, the temperature, the draws dropped outside the prior box, and per
    parameter the raw chain's standard deviation, the adjusted one and the fit's (the
    noise sandwich's, which the adjustment aims at)."""
    info = chain.adjustment
    raw = chain.samples(discard, adjusted=False)
    adjusted, dropped = chain.adjusted(discard)
    out: dict[str, Any] = {
        "method": info.get("method", "none"),
        "reason": info.get("reason"),
        "temperature": info.get("temperature"),
        "dropped": int(dropped),
        "kept": int(adjusted.shape[0]),
        "sd_raw": raw.std(axis=0, ddof=1).tolist() if raw.shape[0] > 1 else None,
        "sd_adjusted": adjusted.std(axis=0, ddof=1).tolist() if adjusted.shape[0] > 1 else None,
        "sd_fit": laplace.sd.tolist(),
    }
    return out

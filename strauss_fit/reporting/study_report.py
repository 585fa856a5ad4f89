"""The study's report: conclusions drawn from the numbers, plots, Markdown, HTML and JSON.

`conclusions` turns the figures of `strauss_fit.study.study.run_study` into plain
statements — for each aspect whether the claim holds, does not, or is mixed, with the
numbers that decide it. Nothing in it is fixed praise: each verdict is a comparison of two
measured values. `write_report` writes ``study.json`` (every figure),
``study.md`` (with the plots as PNG files beside it) and ``study.html`` (self-contained:
the plots are embedded as base64 PNG), with the one document builder
(`strauss_fit.reporting.document.Document`) and figure helper
(`strauss_fit.reporting.figures`) of every report.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import StraussFitError
from ..io.files import Outputs, check_writable
from .document import Document
from .figures import new_figure, png_bytes

FILES = (
    "study.json",
    "study.md",
    "study.html",
    "fig-consistency.png",
    "fig-independence.png",
    "fig-uniformity.png",
    "fig-expressiveness.png",
)


def _pct(x: float | None) -> str:
    return "n/a" if x is None else f"{100 * x:.1f} %"


def _num(x: float | None, digits: int = 3) -> str:
    if x is None:
        return "∞"
    if x != 0 and (abs(x) >= 1e4 or abs(x) < 1e-3):
        return f"{x:.{digits - 1}e}"
    return f"{x:.{digits}g}"


def _verdict(holds: bool | None) -> str:
    return {True: "holds", False: "does not hold", None: "mixed"}[holds]


def _distinct(p1: float, p2: float, n: int) -> bool:
    """Whether two fractions of n draws each differ by more than twice their standard
    error (a two-proportion z-test at about 95 %)."""
    pooled = (p1 + p2) / 2
    se = (2 * pooled * (1 - pooled) / max(n, 1)) ** 0.5
    return abs(p1 - p2) > 2 * se if se > 0 else p1 != p2


# --- conclusions ------------------------------------------------------------------------------


def conclusions(study: dict[str, Any]) -> list[dict[str, Any]]:
    """One entry per aspect: ``aspect``, ``verdict`` (holds / does not hold / mixed) and
    ``statements`` (plain sentences with the deciding numbers)."""
    return [
        _consistency(study["consistency"]),
        _independence(study["independence"]),
        _uniformity(study["uniformity"]),
        _expressiveness(study["expressiveness"]),
    ]


def _consistency(c: dict[str, Any]) -> dict[str, Any]:
    """Part 1's verdict: whether Strauss's ranges create energy less often than a novice's
    Phong settings up to 80°, with the shares, how much energy, toward grazing, who the
    offenders are and whether the difference exceeds the sampling noise."""
    p, pl, s = (c[k]["caps"]["80"] for k in ("phong", "phong_log_exponent", "strauss"))
    lines = _energy_lines(c, p, pl, s) + _offender_lines(c, p, s)
    count = c["strauss"]["count"]
    noise = [
        label
        for label, q in (("uniform n", p["fraction"]), ("log-uniform n", pl["fraction"]))
        if not _distinct(s["fraction"], q, count)
    ]
    if noise:
        lines.append(
            f"With {count} draws per model, the difference to Phong with {' and '.join(noise)} is within "
            "sampling noise (two-proportion test, about 95 %)."
        )
    holds, claim = _energy_claim(p, pl, s, noise)
    lines.append(claim)
    key = (
        f"albedo > 1 at some angle ≤ 80°: Phong {_pct(p['fraction'])} (n uniform), {_pct(pl['fraction'])} "
        f"(n log-uniform); Strauss {_pct(s['fraction'])}"
    )
    return {"aspect": "consistency (energy)", "verdict": _verdict(holds), "key": key, "statements": lines}


def _energy_lines(c: dict[str, Any], p: dict[str, Any], pl: dict[str, Any], s: dict[str, Any]) -> list[str]:
    """The statements of how often and how much each model creates energy (``p``, ``pl``,
    ``s``: the 80° cap's figures of Phong with n uniform and log-uniform, and of Strauss),
    toward grazing incidence, and the white matte Strauss surface's albedo."""
    angles = c["angles_deg"]
    lines = [
        f"Up to 80° of incidence, {_pct(p['fraction'])} of novice Phong sets (n uniform in [1, 1000]) and "
        f"{_pct(pl['fraction'])} with n log-uniform reflect more light than they receive, against "
        f"{_pct(s['fraction'])} of Strauss sets (quadrature accuracy {_num(c['accuracy']['stated'], 2)}; a set counts "
        "only if it exceeds 1 by more than that).",
    ]
    if s["fraction"] > 0 or p["fraction"] > 0 or pl["fraction"] > 0:
        lines.append(
            f"How much energy is created (95th percentile of the excess over 1 among offenders): Strauss "
            f"{_num(s['excess_p95'])}, Phong {_num(p['excess_p95'])} (uniform n), "
            f"{_num(pl['excess_p95'])} (log-uniform n)."
        )
    g = {k: c[k]["caps"]["89"]["fraction"] for k in ("phong", "phong_log_exponent", "strauss")}
    lines.append(
        f"Toward grazing incidence (up to 89°) the fractions rise to {_pct(g['phong'])} (Phong, uniform n), "
        f"{_pct(g['phong_log_exponent'])} (log-uniform n) and {_pct(g['strauss'])} (Strauss): neither model "
        "multiplies its highlight by cos α, so a wide lobe's albedo grows like 1/cos α in both."
    )
    white = c.get("strauss_white_matte_albedo")
    if white:
        k60 = int(np.argmin(np.abs(np.asarray(angles) - 60)))
        k80 = int(np.argmin(np.abs(np.asarray(angles) - 80)))
        lines.append(
            f"A white matte Strauss surface (C = 1, s = m = t = 0) has albedo {white[k60]:.4f} at "
            f"{angles[k60]:g}° and {white[k80]:.4f} at {angles[k80]:g}°: its off-specular term k_j·j is "
            "added on top of a diffuse term that already reflects everything."
        )
    return lines


def _offender_lines(c: dict[str, Any], p: dict[str, Any], s: dict[str, Any]) -> list[str]:
    """The statements of what the sets that create energy look like, per model (none for a
    model without offenders)."""
    lines = []
    offenders = c["strauss"].get("offenders", {})
    if s["fraction"] > 0 and offenders.get("max_color", {}).get("median_offenders") is not None:
        lines.append(
            f"Strauss offenders have bright colours and low smoothness (median max(C) "
            f"{offenders['max_color']['median_offenders']:.2f} vs {offenders['max_color']['median_all']:.2f} "
            f"overall; median s {offenders['smoothness']['median_offenders']:.2f} vs "
            f"{offenders['smoothness']['median_all']:.2f})."
        )
    po = c["phong"].get("offenders", {})
    if p["fraction"] > 0 and po.get("exponent", {}).get("median_offenders") is not None:
        lines.append(
            f"Phong offenders have wide lobes (median n {po['exponent']['median_offenders']:.3g} vs "
            f"{po['exponent']['median_all']:.3g} overall) and strong coefficients (median ks "
            f"{po['ks']['median_offenders']:.2f})."
        )
    return lines


def _energy_claim(
    p: dict[str, Any], pl: dict[str, Any], s: dict[str, Any], noise: list[str]
) -> tuple[bool | None, str]:
    """Whether the claim holds (None: mixed or undecided) and the sentence that says so,
    from the 80° shares and which Phong comparisons are within sampling noise (``noise``)."""
    if s["fraction"] < min(p["fraction"], pl["fraction"]) and len(noise) == 2:
        return None, (
            "So the claim is not decided by this run: Strauss creates energy less often than Phong, but "
            "by less than the sampling noise; use --size full."
        )
    if s["fraction"] < min(p["fraction"], pl["fraction"]):
        return True, "So the claim holds here: Strauss's ranges make energy creation rarer than Phong's" + (
            f" (clearly so only against Phong with {'log-uniform n' if noise == ['uniform n'] else 'uniform n'})."
            if noise
            else "."
        )
    if s["fraction"] > max(p["fraction"], pl["fraction"]):
        return False, (
            "So the claim does not hold in frequency: a uniformly drawn Strauss set creates energy more "
            "often than a novice Phong set, although "
            + (
                "by less."
                if s["excess_p95"] < min(p["excess_p95"] or np.inf, pl["excess_p95"] or np.inf)
                else "not by less."
            )
        )
    return None, (
        "So the answer depends on how a novice sets Phong's exponent: Strauss creates energy less often "
        "than Phong with log-uniform n and more often than with uniform n (which mostly gives narrow, "
        "weak lobes)."
    )


def _independence(d: dict[str, Any]) -> dict[str, Any]:
    summary = d["summary"]
    if "strauss" not in summary or "phong" not in summary:
        return {"aspect": "independence", "verdict": "mixed", "statements": ["No image could be analysed."]}
    s, p = summary["strauss"], summary["phong"]
    lines = [
        f"On {d['images']} sphere images ({d['by_origin'].get('phong', 0)} Phong-rendered, "
        f"{d['by_origin'].get('strauss', 0)} Strauss-rendered), the scale-free condition number of the Fisher "
        f"information is {_num(s['condition_scale_free_median'])} (median) for Strauss's C, s, m and "
        f"{_num(p['condition_scale_free_median'])} for Phong's identifiable set (kd·Cd, ks·Cs, log n).",
        f"The largest posterior correlation between two parameters is {s['max_abs_correlation_median']:.3f} "
        "for Strauss "
        f"(median over images; most often {', '.join(s['most_correlated_pairs'])}) and "
        f"{p['max_abs_correlation_median']:.3f} for Phong (most often {', '.join(p['most_correlated_pairs'])}).",
    ]
    corr = np.asarray(s["median_abs_correlation"])
    labels = s["labels"]
    cm = float(np.median([corr[i, labels.index("m")] for i in range(3)]))
    cs = float(np.median([corr[i, labels.index("s")] for i in range(3)]))
    lines.append(
        f"In Strauss the colour is entangled with metalness (median |corr| {cm:.2f}) and smoothness "
        f"({cs:.2f}): the diffuse term is (1 − ms)(1 − s³)·C, so a darker C and a larger m or s look alike "
        "unless the highlight's colour and width separate them."
    )
    pu = summary.get("phong_user")
    st = summary.get("strauss_with_t")
    if pu:
        lines.append(
            f"As users set Phong (kd, Cd, ks, Cs, n separately) the Fisher information is singular in "
            f"{_pct(pu['singular_fraction'])} of the images: only kd·Cd and ks·Cs reach the image, so those "
            "parameters are exactly dependent — the dependence Strauss's claim is about."
        )
    if st:
        lines.append(
            f"Strauss's transparency in a local image only dims the surface: with t added, the condition "
            f"number rises to {_num(st['condition_scale_free_median'])} (singular in "
            f"{_pct(st['singular_fraction'])} of the images)."
        )
    sk, pk = s["condition_scale_free_median"], p["condition_scale_free_median"]
    if sk is not None and pk is not None and sk < pk:
        holds = True
        lines.append("So the claim holds: Strauss's parameters are better separated by the images than Phong's.")
    elif pu and pu["singular_fraction"] > 0.5:
        holds = None
        lines.append(
            "So the claim is mixed: Phong as users parameterise it is exactly redundant, which Strauss "
            "avoids; but against Phong's identifiable products Strauss's parameters are more entangled "
            "in images, so each is harder to pin down from a picture."
        )
    else:
        holds = False
        lines.append(
            "So the claim does not hold for the images analysed: Strauss's parameters are more entangled than Phong's."
        )
    key = f"scale-free condition number (median): Strauss C,s,m {_num(sk)}, Phong kd·Cd,ks·Cs,log n {_num(pk)}" + (
        f"; Phong kd,Cd,ks,Cs,n singular in {_pct(pu['singular_fraction'])} of images" if pu else ""
    )
    return {"aspect": "independence", "verdict": _verdict(holds), "key": key, "statements": lines}


def _uniformity(u: dict[str, Any]) -> dict[str, Any]:
    s = u["strauss"]["smoothness"]
    n_lin = u["phong"]["exponent (linear steps)"]
    n_geo = u["phong"]["exponent (geometric steps)"]
    lines = [
        f"Per equal step across its range ({u['steps'] - 1} steps, {u['bases']} base material(s) per model), the image "
        f"changes unevenly by a coefficient of variation of {_num(s['cv'])} for s, against {_num(n_lin['cv'])} for "
        f"Phong's n stepped linearly in [1, 1000] and {_num(n_geo['cv'])} stepped geometrically.",
        f"s's largest step lies between s = {s['largest_step_between'][0]:.2f} and {s['largest_step_between'][1]:.2f} "
        f"({_num(s['max_over_mean'])} × the mean step); n's linear largest step lies between "
        f"{n_lin['largest_step_between'][0]:.4g} and {n_lin['largest_step_between'][1]:.4g} "
        f"({_num(n_lin['max_over_mean'])} × the mean).",
    ]
    others = ", ".join(f"{name} {_num(v['cv'])}" for name, v in u["strauss"].items() if name != "smoothness")
    phong_others = ", ".join(
        f"{name} {_num(v['cv'])}" for name, v in u["phong"].items() if not name.startswith("exponent")
    )
    lines.append(f"Other parameters (coefficient of variation): Strauss {others}; Phong {phong_others}.")
    if s["cv"] is not None and n_lin["cv"] is not None and n_geo["cv"] is not None:
        if s["cv"] < min(n_lin["cv"], n_geo["cv"]):
            holds = True
            lines.append(
                "So the claim holds: s changes the image more evenly than Phong's exponent, stepped either way."
            )
        elif s["cv"] < n_lin["cv"]:
            holds = None
            lines.append(
                "So the claim is mixed: s is more even than n stepped linearly (as a novice would), but not "
                "more even than n stepped geometrically."
            )
        else:
            holds = False
            lines.append("So the claim does not hold: s is not more even than Phong's exponent.")
    else:
        holds = None
    key = (
        f"CV of the ΔE steps: s {_num(s['cv'])}, Phong n {_num(n_lin['cv'])} (linear steps), "
        f"{_num(n_geo['cv'])} (geometric steps)"
    )
    return {"aspect": "uniformity", "verdict": _verdict(holds), "key": key, "statements": lines}


def _expressiveness(e: dict[str, Any]) -> dict[str, Any]:
    """Part 4's verdict: which model reproduces the other's renders more closely (not part
    of Strauss's claim), with the medians, the energy-creating sources and the worst matched."""
    a = e["phong_to_strauss"]["delta_e2000_mean"]
    b = e["strauss_to_phong"]["delta_e2000_mean"]
    lines = []
    if a.get("count") and b.get("count"):
        lines.append(
            f"Strauss reproduces novice Phong materials with a median CIEDE2000 of {_num(a['median'])} "
            f"(90th percentile {_num(a['p90'])}, {_pct(a['below_1'])} below 1, i.e. hard to see) over "
            f"{a['count']} materials; Phong reproduces opaque Strauss materials with a median of "
            f"{_num(b['median'])} (90th percentile {_num(b['p90'])}, {_pct(b['below_1'])} below 1)."
        )
        cons, crea = (
            e["phong_to_strauss"]["energy_conserving_sources"],
            e["phong_to_strauss"]["energy_creating_sources"],
        )
        if cons.get("count") and crea.get("count"):
            lines.append(
                f"Phong sources that create energy are matched worse (median {_num(crea['median'])}) than those "
                f"that do not ({_num(cons['median'])})."
            )
        lines += _worst_matched_lines(e)
        holds = True if a["median"] <= b["median"] else False
        lines.append(
            "Expressiveness is not part of Strauss's claim; "
            + (
                "here Strauss is at least as expressive as Phong."
                if holds
                else "here Strauss is the less expressive model: it covers fewer appearances than Phong "
                "(by design — fewer, "
                "bounded parameters)."
            )
        )
    else:
        holds = None
        lines.append("No conversion succeeded.")
    errors = e["phong_to_strauss"]["errors"] + e["strauss_to_phong"]["errors"]
    if errors:
        lines.append(f"{errors} conversion(s) failed and are excluded.")
    key = (
        f"median ΔE2000: Phong → Strauss {_num(a.get('median'))}, Strauss → Phong {_num(b.get('median'))}"
        if a.get("count") and b.get("count")
        else "no conversion succeeded"
    )
    return {
        "aspect": "expressiveness",
        "verdict": "Strauss ≥ Phong" if holds else ("Strauss < Phong" if holds is False else "n/a"),
        "key": key,
        "statements": lines,
    }


def _worst_matched_lines(e: dict[str, Any]) -> list[str]:
    """The statements of what the worst-matched quarter of each direction's sources look
    like (none for a direction the study did not describe)."""
    lines = []
    worst = e.get("worst_matched", {}).get("phong_to_strauss", {})
    if worst.get("exponent"):
        lines.append(
            f"The worst-matched quarter of the Phong sources ({worst['worst_count']}) have median n "
            f"{worst['exponent']['median_worst']:.3g} (all: {worst['exponent']['median_all']:.3g}), "
            f"ks {worst['ks']['median_worst']:.2f} (all: {worst['ks']['median_all']:.2f}) and brightest "
            f"diffuse channel {worst['max_kd_cd']['median_worst']:.2f} "
            f"(all: {worst['max_kd_cd']['median_all']:.2f}). Strauss ties a highlight's strength to its "
            "width (r_n = s³ with h = 3/(1 − s)) and dims the diffuse term as s grows, so a visible lobe "
            "with Phong's free ks has no exact counterpart."
        )
    worst_s = e.get("worst_matched", {}).get("strauss_to_phong", {})
    if worst_s.get("smoothness"):
        lines.append(
            f"The worst-matched quarter of the Strauss sources have median s "
            f"{worst_s['smoothness']['median_worst']:.2f} (all: {worst_s['smoothness']['median_all']:.2f}) "
            f"and m {worst_s['metalness']['median_worst']:.2f} (all: {worst_s['metalness']['median_all']:.2f})."
        )
    return lines


# --- plots ------------------------------------------------------------------------------------


#: Resolution of the study's figures.
DPI = 110


def _png(fig) -> bytes:
    return png_bytes(fig, DPI)


def plots(study: dict[str, Any]) -> dict[str, bytes]:
    """The four figures as PNG bytes, by file name (the independence figure only when both
    models' images could be analysed)."""
    out = {"fig-consistency.png": _consistency_plot(study["consistency"])}
    independence = _independence_plot(study["independence"])
    if independence is not None:
        out["fig-independence.png"] = independence
    out["fig-uniformity.png"] = _uniformity_plot(study["uniformity"])
    out["fig-expressiveness.png"] = _expressiveness_plot(study["expressiveness"]["materials"])
    return out


def _consistency_plot(c: dict[str, Any]) -> bytes:
    """Part 1's figure: the share of sets creating energy up to each angle, and the median
    albedo per angle, per model (with the white matte Strauss surface)."""
    angles = c["angles_deg"]
    fig = new_figure(figsize=(10, 3.6))
    axes = fig.subplots(1, 2)
    for key, label, style in (
        ("phong", "Phong, n uniform", "-"),
        ("phong_log_exponent", "Phong, n log-uniform", "--"),
        ("strauss", "Strauss", "-"),
    ):
        axes[0].plot(angles, np.asarray(c[key]["by_angle"]) * 100, style, label=label)
        axes[1].plot(angles, c[key]["worst_at_angle_median"], style, label=label)
    axes[1].plot(angles, c["strauss_white_matte_albedo"], ":", color="k", label="Strauss white matte")
    axes[0].set(
        xlabel="largest angle of incidence (°)",
        ylabel="sets with albedo > 1 (%)",
        title="energy created at some angle up to θ",
    )
    axes[1].set(xlabel="angle of incidence (°)", ylabel="albedo (max channel)", title="median albedo", yscale="log")
    axes[1].axhline(1.0, color="grey", lw=0.8)
    for ax in axes:
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    return _png(fig)


def _independence_plot(independence: dict[str, Any]) -> bytes | None:
    """Part 2's figure: both models' median absolute correlations and the scale-free
    condition number of every image; None unless both models were analysed."""
    d = independence["summary"]
    if "strauss" not in d or "phong" not in d:
        return None
    fig = new_figure(figsize=(15, 4.2))
    axes = fig.subplots(1, 3)
    for ax, key, title in ((axes[0], "strauss", "Strauss |corr|"), (axes[1], "phong", "Phong |corr|")):
        matrix = np.asarray(d[key]["median_abs_correlation"])
        im = ax.imshow(matrix, vmin=0, vmax=1, cmap="viridis")
        ax.set_xticks(range(len(d[key]["labels"])), d[key]["labels"], rotation=60, fontsize=8)
        ax.set_yticks(range(len(d[key]["labels"])), d[key]["labels"], fontsize=8)
        ax.set_title(f"{title} (median over images)")
        fig.colorbar(im, ax=ax, fraction=0.046)
    per = independence["per_image"]
    for k, (key, _label) in enumerate(
        (("strauss", "Strauss C,s,m"), ("strauss_with_t", "Strauss +t"), ("phong", "Phong D,S,log n"))
    ):
        values = [r[key]["condition_scale_free"] for r in per]
        finite = [v for v in values if v is not None]
        axes[2].scatter(np.full(len(finite), k) + np.linspace(-0.15, 0.15, len(finite)), finite, s=12)
        singular = len(values) - len(finite)
        if singular:
            axes[2].annotate(f"{singular} singular", (k, max(finite or [1.0])), fontsize=8)
    axes[2].set_yscale("log")
    axes[2].set_xticks(range(3), ["Strauss C,s,m", "Strauss +t", "Phong D,S,log n"], fontsize=8)
    axes[2].set_title("scale-free condition number per image")
    axes[2].grid(alpha=0.3)
    return _png(fig)


def _uniformity_plot(u: dict[str, Any]) -> bytes:
    """Part 3's figure: each parameter's ΔE per step relative to its mean step, per model."""
    fig = new_figure(figsize=(10, 3.6))
    axes = fig.subplots(1, 2, sharey=True)
    for ax, model in ((axes[0], "strauss"), (axes[1], "phong")):
        for name, v in u[model].items():
            profile = np.asarray(v["mean_profile"])
            mean = profile.mean() if profile.mean() > 0 else 1.0
            x = (np.arange(profile.size) + 0.5) / profile.size
            ax.plot(x, profile / mean, marker=".", label=f"{name} (mean ΔE {v['mean_step']:.2g})")
        ax.axhline(1.0, color="grey", lw=0.8)
        ax.set(
            xlabel="position of the step in the parameter's range",
            title=f"{model.capitalize()}: ΔE per step / mean",
            yscale="log",
        )
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("step ΔE2000 relative to the mean step")
    return _png(fig)


def _expressiveness_plot(e: dict[str, Any]) -> bytes:
    """Part 4's figure: the histogram of the conversions' residuals in each direction."""
    fig = new_figure(figsize=(6.5, 3.6))
    ax = fig.subplots()
    values = {
        "Phong → Strauss": [r["residual"]["delta_e2000_mean"] for r in e["phong_to_strauss"] if r["status"] == "ok"],
        "Strauss → Phong": [r["residual"]["delta_e2000_mean"] for r in e["strauss_to_phong"] if r["status"] == "ok"],
    }
    everything = [v for vs in values.values() for v in vs if v > 0]
    if everything:
        bins = np.geomspace(max(min(everything), 1e-4), max(max(everything), 1e-3) * 1.01, 25)
        for label, vs in values.items():
            ax.hist(np.clip(vs, bins[0], None), bins=bins, alpha=0.6, label=f"{label} ({len(vs)})")
        ax.set_xscale("log")
    ax.axvline(1.0, color="grey", lw=0.8)
    ax.set(xlabel="CIEDE2000, mean over the sphere", ylabel="materials", title="residual of the conversions")
    ax.legend(fontsize=8)
    return _png(fig)


# --- documents --------------------------------------------------------------------------------


TITLE = "Strauss vs Phong: the intuitive-parameter study"
_STYLE = (
    "body{font-family:system-ui,sans-serif;max-width:70em;margin:2em auto;padding:0 1em;line-height:1.45}"
    "table{border-collapse:collapse;margin:1em 0;font-size:0.92em}td,th{border:1px solid #ccc;padding:0.3em 0.6em;"
    "vertical-align:top}th{background:#f3f3f3}img{max-width:100%}figcaption{font-size:0.9em;color:#555}"
)


def study_table(doc: Document, header: list[str], rows: list[list[Any]]) -> None:
    """A table of the study's report; its header is written as is (a '|' in it is not
    escaped in the Markdown), as every study table always has been."""
    doc.table(header, rows, escape_header=False)


def study_figure(doc: Document, images: dict[str, bytes], name: str, caption: str) -> None:
    """The figure ``name`` of ``images`` with its caption below it in the Markdown (linked
    there even when it was not drawn)."""
    doc.image(name, images.get(name), caption, caption=True)


def study_document(study: dict[str, Any], verdicts: list[dict[str, Any]], images: dict[str, bytes]) -> Document:
    """The report's text, tables and figures (``images``: the PNGs of `plots`): the
    conclusions, then one section per part, then the timing line."""
    doc = Document()
    _conclusions_section(doc, study, verdicts)
    _consistency_section(doc, study["consistency"], images)
    _independence_section(doc, study["independence"], images)
    _uniformity_section(doc, study["uniformity"], images)
    _expressiveness_section(doc, study["expressiveness"], images)
    doc.para("Timing (s): " + ", ".join(f"{k.removesuffix('_s')} {v:.1f}" for k, v in study["timing"].items()))
    return doc


def _conclusions_section(doc: Document, study: dict[str, Any], verdicts: list[dict[str, Any]]) -> None:
    """The title, the run in one line, and the conclusions: one table row per aspect, then
    each aspect's statements."""
    config = study["config"]
    doc.heading(TITLE, 1)
    doc.para(
        f"Run '{config['name']}' (seed {config['seed']}), {study['timing']['total_s']:.0f} s. "
        "Method, definitions and how to read this report: docs/study.md in the strauss-fit documentation. "
        "Every number below is in study.json."
    )
    doc.heading("Conclusions")
    study_table(
        doc,
        ["aspect", "claim", "deciding numbers", "in short"],
        [[v["aspect"], v["verdict"], v["key"], v["statements"][-1]] for v in verdicts],
    )
    for v in verdicts:
        doc.heading(f"{v['aspect']}: {v['verdict']}", 3)
        doc.bullets(v["statements"])


def _consistency_section(doc: Document, c: dict[str, Any], images: dict[str, bytes]) -> None:
    """Part 1: how the albedo was computed, the share of sets creating energy per angle
    cap and model, and its figure."""
    doc.heading("1. Consistency: energy created by novice settings")
    doc.para(
        f"{c['phong']['count']} sets per model; albedo at {len(c['angles_deg'])} angles of incidence from "
        f"{c['angles_deg'][0]:g}° to {c['angles_deg'][-1]:g}°; Gauss–Legendre quadrature with "
        f"{c['nodes']} nodes per axis about the mirror direction, stated accuracy "
        f"{_num(c['accuracy']['stated'], 2)} (largest of: node doubling "
        f"{_num(c['accuracy']['doubling_strauss'], 2)} Strauss / {_num(c['accuracy']['doubling_phong'], 2)} "
        f"Phong; Lambertian closed form {_num(c['accuracy']['lambertian_closed_form'], 2)}; Phong lobe at "
        f"normal incidence {_num(c['accuracy']['phong_normal_incidence_closed_form'], 2)})."
    )
    rows = []
    for key, label in (
        ("phong", "Phong (n uniform)"),
        ("phong_log_exponent", "Phong (n log-uniform)"),
        ("strauss", "Strauss"),
    ):
        caps = c[key]["caps"]
        rows.append(
            [label]
            + [_pct(caps[k]["fraction"]) for k in caps]
            + [_num(caps["80"]["excess_p95"]), _num(caps["89"]["excess_max"])]
        )
    study_table(
        doc,
        ["model", "albedo > 1 up to 60°", "up to 80°", "up to 89°", "excess p95 (≤ 80°)", "largest excess (≤ 89°)"],
        rows,
    )
    study_figure(
        doc,
        images,
        "fig-consistency.png",
        "Left: share of sets whose albedo exceeds 1 at some angle up to θ. Right: median albedo per angle (log scale).",
    )


def _independence_section(doc: Document, d: dict[str, Any], images: dict[str, bytes]) -> None:
    """Part 2: how the Fisher information was computed, its condition numbers and
    correlations per parameterisation, and its figure."""
    doc.heading("2. Independence: what the same images tell about each model's parameters")
    doc.para(
        f"{d['images']} images of the conversion scene; Fisher information J^T J/σ² with σ = 1 % of each "
        "image's 98th percentile; the scale-free condition number is that of the Fisher information "
        "rescaled to unit diagonal (invariant to units and reparameterisation of each parameter); "
        "'unit range' uses every parameter on [0, 1] (Phong's n as log n / log 10⁴)."
    )
    rows = []
    for key, label in (
        ("strauss", "Strauss C, s, m"),
        ("strauss_with_t", "Strauss C, s, m, t"),
        ("phong", "Phong kd·Cd, ks·Cs, log n"),
        ("phong_user", "Phong kd, Cd, ks, Cs, n"),
    ):
        s = d["summary"].get(key)
        if not s:
            continue
        rows.append(
            [
                label,
                _pct(s["singular_fraction"]),
                _num(s["condition_scale_free_median"]),
                _num(s["condition_scale_free_p90"]),
                _num(s["condition_unit_range_median"]),
                f"{s['max_abs_correlation_median']:.3f}",
                f"{s['mean_abs_correlation_median']:.3f}",
                ", ".join(s["most_correlated_pairs"]),
            ]
        )
    study_table(
        doc,
        [
            "parameters",
            "singular",
            "condition (scale-free), median",
            "p90",
            "condition (unit range), median",
            "max |corr|, median",
            "mean |corr|, median",
            "most correlated pairs",
        ],
        rows,
    )
    study_figure(
        doc,
        images,
        "fig-independence.png",
        "Median absolute posterior correlations, and the scale-free "
        "condition number of each image's Fisher information.",
    )


def _uniformity_section(doc: Document, u: dict[str, Any], images: dict[str, bytes]) -> None:
    """Part 3: how the sweeps were made, the evenness of every parameter's steps, and its
    figure."""
    doc.heading("3. Uniformity: image change per equal parameter step")
    doc.para(
        f"{u['bases']} base material(s) per model drawn as in part 1 (Phong's n log-uniform, so that the "
        f"bases' highlights are resolved), {u['steps']} equally spaced values "
        f"per parameter, {u['image_size']}-pixel images; CIEDE2000 (mean over the sphere) between successive "
        "images on a common exposure. Coefficient of variation (CV) of the steps: 0 = perfectly even."
    )
    rows = []
    for model in ("strauss", "phong"):
        for name, v in u[model].items():
            rows.append(
                [
                    model.capitalize(),
                    name,
                    _num(v["mean_step"]),
                    _num(v["cv"]),
                    _num(v["max_over_mean"]),
                    f"{v['largest_step_between'][0]:.4g} → {v['largest_step_between'][1]:.4g}",
                ]
            )
    study_table(doc, ["model", "parameter", "mean step ΔE", "CV of steps", "largest / mean", "largest step"], rows)
    study_figure(
        doc,
        images,
        "fig-uniformity.png",
        "ΔE2000 of each step relative to the parameter's mean step (averaged over the base materials).",
    )


def _expressiveness_section(doc: Document, e: dict[str, Any], images: dict[str, bytes]) -> None:
    """Part 4: the conversion scene, the residuals' distribution in each direction, and
    its figure."""
    a, b = e["phong_to_strauss"], e["strauss_to_phong"]
    doc.heading("4. Expressiveness: converting between the models")
    doc.para(
        f"Conversion scene: {e['scene']['width']}×{e['scene']['height']} pixels, "
        f"{len(e['scene']['lights'])} light(s); Phong sources drawn as in part 1, Strauss sources opaque "
        "with C, s, m uniform. Residual = CIEDE2000 between the source's image and the fitted model's, "
        "mean over the sphere."
    )
    rows = []
    for label, dist in (
        ("Phong → Strauss", a["delta_e2000_mean"]),
        ("  … energy-conserving sources", a["energy_conserving_sources"]),
        ("  … energy-creating sources", a["energy_creating_sources"]),
        ("Strauss → Phong", b["delta_e2000_mean"]),
    ):
        if not dist.get("count"):
            rows.append([label, "0", "", "", "", ""])
            continue
        rows.append(
            [
                label,
                str(dist["count"]),
                _num(dist["median"]),
                _num(dist["p90"]),
                _num(dist["max"]),
                _pct(dist["below_1"]),
            ]
        )
    study_table(doc, ["direction", "materials", "median ΔE", "p90", "max", "ΔE < 1"], rows)
    study_figure(doc, images, "fig-expressiveness.png", "Distribution of the conversions' residuals.")


def write_report(study: dict[str, Any], outdir: str | Path, *, force: bool = False) -> list[Path]:
    """Write study.json, study.md, study.html and the PNG plots into ``outdir`` (created
    if missing; its parent must exist), all or none (each file is written in full to a
    temporary file, then all are renamed together). Existing files are refused without
    ``force``."""
    return write_study_files(study, outdir, FILES, conclusions, plots, study_document, force=force)


def write_study_files(
    study: dict[str, Any],
    outdir: str | Path,
    files: Sequence[str],
    verdicts_of: Callable[[dict[str, Any]], Any],
    images_of: Callable[[dict[str, Any]], dict[str, bytes]],
    document_of: Callable[[dict[str, Any], Any, dict[str, bytes]], Document],
    *,
    force: bool = False,
) -> list[Path]:
    """The one writer of a study's report: ``files`` checked first, then the JSON (the study
    with ``verdicts_of(study)`` as its conclusions), the PNGs of ``images_of`` and the
    Markdown and HTML of ``document_of(study, verdicts, images)``, all or none; ``outdir`` is
    created if missing (its parent must exist) and removed again, if empty, on failure."""
    outdir = Path(outdir)
    if outdir.exists() and not outdir.is_dir():
        raise StraussFitError(f"output path is not a folder: {outdir}")
    created = False
    if not outdir.exists():
        if not outdir.parent.is_dir():
            raise StraussFitError(f"output folder's parent does not exist: {outdir.parent}")
        try:
            outdir.mkdir()
        except OSError as exc:
            raise StraussFitError(f"cannot create {outdir}: {exc.strerror or exc}") from None
        created = True
    try:
        for name in files:
            check_writable(outdir / name, force)
        verdicts = verdicts_of(study)
        document = dict(study)
        document["conclusions"] = verdicts
        images = images_of(study)
        doc = document_of(study, verdicts, images)
        with Outputs(force=force) as out:
            out.add_json(outdir / "study.json", document)
            for name, data in images.items():
                out.add_bytes(outdir / name, data)
            out.add_text(outdir / "study.md", doc.markdown())
            out.add_text(outdir / "study.html", doc.html(TITLE, _STYLE, spaced=True))
            return out.commit(final=True)
    except BaseException:
        if created:
            try:
                outdir.rmdir()  # only if empty
            except OSError:
                pass
        raise


def check_outputs(outdir: str | Path, force: bool, files: Sequence[str] = FILES) -> None:
    """Refuse early (before the study runs) if the outputs ``files`` exist and ``force`` is
    not set."""
    outdir = Path(outdir)
    if outdir.exists() and not outdir.is_dir():
        raise StraussFitError(f"output path is not a folder: {outdir}")
    if not outdir.exists():
        if not outdir.parent.is_dir():
            raise StraussFitError(f"output folder's parent does not exist: {outdir.parent}")
        return
    for name in files:
        check_writable(outdir / name, force)

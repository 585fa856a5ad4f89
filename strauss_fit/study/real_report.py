"""The measured-material parts of the study's report (`strauss_fit.study.real`).

`real_conclusions` turns the ``merl`` and ``capture`` entries of a study into
verdicts in the style of `strauss_fit.reporting.study_report.conclusions`: each a
comparison of measured values, with the numbers that decide it, no fixed text praising
either model. `write_study_report` writes the whole report — the four parts of
`strauss_fit.reporting.study_report` and, when the study has them, sections 5 and 6
with their tables and the figure ``fig-merl.png`` — all files or none.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..reporting.document import Document
from ..reporting.figures import new_figure, png_bytes
from ..reporting.study_report import (
    DPI,
    FILES,
    _num,
    _pct,
    check_outputs,
    conclusions,
    plots,
    study_document,
    study_figure,
    study_table,
    write_study_files,
)
from .real import CLASSES

#: The figure of part 5.
MERL_FIGURE = "fig-merl.png"
MERL_ASPECT = "expressiveness on measured materials"
CAPTURE_ASPECT = "real photographs"


def report_files(study: dict[str, Any] | None = None, *, merl: bool | None = None) -> tuple[str, ...]:
    """The files the report of ``study`` (or of a study with or without part 5) writes."""
    with_merl = bool(study and "merl" in study) if merl is None else merl
    return FILES + ((MERL_FIGURE,) if with_merl else ())


# --- conclusions ------------------------------------------------------------------------------


def real_conclusions(study: dict[str, Any]) -> list[dict[str, Any]]:
    """The verdicts of parts 5 and 6, for those the study ran."""
    out = []
    if "merl" in study:
        out.append(_merl_verdict(study["merl"], study.get("expressiveness")))
    if "capture" in study:
        out.append(_capture_verdict(study["capture"]))
    return out


def all_conclusions(study: dict[str, Any]) -> list[dict[str, Any]]:
    """The four aspects of `strauss_fit.reporting.study_report.conclusions` and parts 5 and 6."""
    return conclusions(study) + real_conclusions(study)


def _merl_verdict(m: dict[str, Any], synthetic: dict[str, Any] | None) -> dict[str, Any]:
    """Part 5's verdict: whether Strauss matches measured materials at least as well as
    Phong, as rendered and clipped at white, with the shares and medians that decide it
    (``synthetic``: part 4's figures, quoted beside them)."""
    a = m["all"]
    s, p = a["strauss"], a["phong"]
    if not s["fitted"] or not p["fitted"]:
        return {
            "aspect": MERL_ASPECT,
            "verdict": "n/a",
            "key": "no measured material could be fitted by both models",
            "statements": [f"{s['errors']} Strauss and {p['errors']} Phong fit(s) failed; nothing to compare."],
        }
    sc, pc = a.get("strauss_clipped"), a.get("phong_clipped")
    clipped = bool(sc and pc and sc["fitted"] and pc["fitted"])
    lines = _merl_overview(m) + _merl_notes(m, clipped, synthetic)
    verdict, conclusion = _merl_conclusion(s, p, sc, pc, clipped)
    lines.append(conclusion)
    key = (
        f"within 1 JND as rendered: Strauss {_pct(s['matched'])}, Phong {_pct(p['matched'])} (median ΔE2000 "
        f"{_num(s['median_delta_e'])}, {_num(p['median_delta_e'])})"
        + (f"; clipped at white: Strauss {_pct(sc['matched'])}, Phong {_pct(pc['matched'])}" if clipped else "")
        + f"; Strauss out of reach {_pct(s['out_of_reach'])}"
    )
    return {"aspect": MERL_ASPECT, "verdict": verdict, "key": key, "statements": lines}


def _merl_overview(m: dict[str, Any]) -> list[str]:
    """The statements of how many materials each model matches, over all and by class."""
    a = m["all"]
    s, p = a["strauss"], a["phong"]
    lines = [
        f"On {a['materials']} MERL materials (Ngan et al.'s Cook–Torrance fits, rendered under "
        f"{len(m['scenes'])} scene(s) at {m['image_size']} px; a material's ΔE is its largest over the scenes), "
        f"Strauss matches {_pct(s['matched'])} within one just-noticeable difference (mean CIEDE2000 ≤ 1; median "
        f"{_num(s['median_delta_e'])}, 90th percentile {_num(s['p90_delta_e'])}) and Phong {_pct(p['matched'])} "
        f"(median {_num(p['median_delta_e'])}, 90th percentile {_num(p['p90_delta_e'])}); Strauss is the closer "
        f"of the two on {_pct(a['strauss_better'])} of the materials.",
    ]
    parts = []
    for label in CLASSES:
        c = m["by_class"][label]
        if not c["materials"] or not c["strauss"]["fitted"] or not c["phong"]["fitted"]:
            continue
        parts.append(
            f"{label} ({c['materials']}): Strauss {_pct(c['strauss']['matched'])} matched, median "
            f"{_num(c['strauss']['median_delta_e'])}, out of reach {_pct(c['strauss']['out_of_reach'])}; Phong "
            f"{_pct(c['phong']['matched'])}, median {_num(c['phong']['median_delta_e'])}"
        )
    if parts:
        lines.append("By class: " + "; ".join(parts) + ".")
    return lines


def _merl_notes(m: dict[str, Any], clipped: bool, synthetic: dict[str, Any] | None) -> list[str]:
    """The statements beside the overview: Strauss out of reach, failed fits, the fits
    clipped at white (when ``clipped``), Strauss's default loss and part 4's medians."""
    a = m["all"]
    s, p = a["strauss"], a["phong"]
    lines = []
    if s["out_of_reach"]:
        lines.append(
            f"Strauss's fit is out of reach on {_pct(s['out_of_reach'])} of the materials (median ΔE there "
            f"{_num(s['median_delta_e_out_of_reach'])}): the target's highlight is brighter than any Strauss "
            "material can be under the scene's lights, or the fit pins the colour at 1 or s at a bound while the "
            "highlight holds the residual — the highlight bound r_s ≤ 1."
        )
    if s["errors"] + p["errors"]:
        lines.append(f"{s['errors']} Strauss and {p['errors']} Phong fit(s) failed and are excluded.")
    if clipped:
        sc, pc = a["strauss_clipped"], a["phong_clipped"]
        over = sum(
            1
            for r in m["materials"]
            if any(scene.get("clipped_pixels", 0) > 0 for scene in r.get("scenes", {}).values())
        )
        lines.append(
            f"Clipped at white, as a camera exposed for the sphere records it ({over} materials have pixels brighter "
            f"than white), both models fitted by least squares to the rest and judged on every pixel: Strauss "
            f"matches {_pct(sc['matched'])} (median {_num(sc['median_delta_e'])}) and Phong {_pct(pc['matched'])} "
            f"(median {_num(pc['median_delta_e'])}); Strauss is the closer on {_pct(a['strauss_better_clipped'])}."
        )
    d = a.get("strauss_default")
    if d and d["fitted"]:
        lines.append(
            f"With its default loss (a robust refit when the least-squares fit visibly misses, so that a highlight "
            f"it cannot reach does not pull the rest of the sphere) Strauss matches {_pct(d['matched'])} of the "
            f"radiance as rendered (median {_num(d['median_delta_e'])}); Phong had no such refit."
        )
    if synthetic:
        x = synthetic.get("phong_to_strauss", {}).get("delta_e2000_mean", {})
        y = synthetic.get("strauss_to_phong", {}).get("delta_e2000_mean", {})
        if x.get("count") and y.get("count"):
            lines.append(
                f"On the models' own renders (part 4) the medians were {_num(x['median'])} (Strauss fitting Phong "
                f"images) and {_num(y['median'])} (Phong fitting Strauss images)."
            )
    return lines


def _merl_conclusion(
    s: dict[str, Any], p: dict[str, Any], sc: dict[str, Any] | None, pc: dict[str, Any] | None, clipped: bool
) -> tuple[str, str]:
    """The verdict and the sentence that draws it: the comparison as rendered (``s``, ``p``),
    and when ``clipped`` also clipped at white (``sc``, ``pc``); "mixed" when the two differ."""
    rendered = _compare(s, p)
    verdict = rendered if not clipped else (rendered if _compare(sc, pc) == rendered else "mixed")
    if verdict == "Strauss ≥ Phong":
        return verdict, (
            "So on measured materials Strauss is at least as expressive as Phong"
            + (" both as rendered and clipped at white" if clipped else "")
            + " (both fitted by least squares; the capture fitter's Phong has a white highlight)."
        )
    if verdict == "Strauss < Phong":
        return verdict, (
            "So on measured materials, too, Strauss is the less expressive model: it matches fewer of them, and less "
            "closely" + (", both as rendered and clipped at white." if clipped else ".")
        )
    if clipped:
        phrase = {
            "Strauss ≥ Phong": "at least as expressive as Phong",
            "Strauss < Phong": "less expressive than Phong",
            "mixed": "neither more nor less expressive than Phong (the share matched and the median disagree)",
        }
        return verdict, (
            f"So the answer depends on what is compared: as rendered Strauss is {phrase[rendered]}, clipped at "
            f"white {phrase[_compare(sc, pc)]}"
            + (
                ": the gap lies in highlights brighter than white, which Strauss's r_s ≤ 1 cannot reach and which "
                "least squares lets pull the rest of the sphere."
                if rendered == "Strauss < Phong"
                else "."
            )
        )
    return verdict, "So on measured materials neither model is more expressive overall: " + (
        "Strauss matches at least as many within one JND but with a larger median ΔE."
        if s["matched"] >= p["matched"]
        else "Strauss has the smaller median ΔE but matches fewer within one JND."
    )


def _compare(s: dict[str, Any], p: dict[str, Any]) -> str:
    """Strauss against Phong on the share matched and the median ΔE: both at least as good,
    both worse, or mixed."""
    share = s["matched"] >= p["matched"]
    median = s["median_delta_e"] <= p["median_delta_e"]
    return "Strauss ≥ Phong" if share and median else "Strauss < Phong" if not share and not median else "mixed"


def _stability_phrase(entry: dict[str, Any]) -> str | None:
    st = entry.get("stability")
    if not st or "halves" not in st:
        return None
    a, b = st["halves"][0]["values"], st["halves"][1]["values"]
    values = ", ".join(f"{name} {_num(a[name])} / {_num(b[name])}" for name in st["parameters"])
    return f"{'stable' if st['stable'] else 'not stable'} ({values})"


def _capture_verdict(c: dict[str, Any]) -> dict[str, Any]:
    models = c["models"]
    ok = {name: e for name, e in models.items() if e["status"] == "ok"}
    lines = [
        f"On {c['source']} ({c['pixels']} sphere pixels × {c['images']} images; fitted on {c['fitted_images']}, "
        f"{c['held_out_images']} held out), the held-out mean CIEDE2000 is "
        + ", ".join(
            f"{name} {_num(e['held_out']['delta_e2000_mean'])} (relative RMS {_num(e['held_out']['relative_rms'])})"
            for name, e in ok.items()
        )
        + "."
    ]
    if ok:
        ranked = sorted(ok, key=lambda name: ok[name]["held_out"]["delta_e2000_mean"])
        lines.append(f"Ranked by held-out ΔE: {' < '.join(ranked)}.")
    for name, e in ok.items():
        phrase = _stability_phrase(e)
        if phrase:
            lines.append(f"Over two disjoint halves of the fitted images, {name}'s lobe is {phrase}.")
    failed = [f"{name} ({e['message']})" for name, e in models.items() if e["status"] != "ok"]
    if failed:
        lines.append("Failed: " + "; ".join(failed) + ".")
    if "strauss" in ok and "phong" in ok:
        s, p = ok["strauss"]["held_out"]["delta_e2000_mean"], ok["phong"]["held_out"]["delta_e2000_mean"]
        verdict = "Strauss ≥ Phong" if s <= p else "Strauss < Phong"
        lines.append(
            "So on these photographs Strauss predicts the held-out images "
            f"{'at least as well as' if s <= p else 'worse than'} Phong (ΔE {_num(s)} against {_num(p)})"
            + (
                f"; its s and m are {'stable' if ok['strauss']['stability']['stable'] else 'not stable'} across halves."
                if "stable" in (ok["strauss"].get("stability") or {})
                else "."
            )
        )
        key = f"held-out ΔE2000: Strauss {_num(s)}, Phong {_num(p)}" + "".join(
            f", {name} {_num(e['held_out']['delta_e2000_mean'])}"
            for name, e in ok.items()
            if name not in ("strauss", "phong")
        )
    else:
        verdict = "n/a"
        lines.append("Strauss and Phong were not both fitted: no comparison.")
        key = "no comparison"
    return {"aspect": CAPTURE_ASPECT, "verdict": verdict, "key": key, "statements": lines}


# --- figure and sections ----------------------------------------------------------------------


def real_plots(study: dict[str, Any]) -> dict[str, bytes]:
    """``fig-merl.png``: Strauss's ΔE against Phong's per measured material, by class, as
    rendered and clipped at white."""
    if "merl" not in study:
        return {}
    materials = study["merl"]["materials"]
    fig = new_figure(figsize=(11.0, 4.8))
    axes = fig.subplots(1, 2, sharex=True, sharey=True)
    panels = (("strauss", "phong", "as rendered"), ("strauss_clipped", "phong_clipped", "clipped at white"))
    values = [
        r[key]["delta_e2000_mean"]
        for r in materials
        for pair in panels
        for key in pair[:2]
        if r.get(key, {}).get("status") == "ok"
    ]
    floor = max(min([v for v in values if v > 0] or [1e-3]) / 2, 1e-4)
    top = max(values + [2.0]) * 1.3
    for ax, (s_key, p_key, title) in zip(axes, panels):
        for label in CLASSES:
            mine = [
                r
                for r in materials
                if r["class"] == label
                and r.get(s_key, {}).get("status") == "ok"
                and r.get(p_key, {}).get("status") == "ok"
            ]
            if not mine:
                continue
            x = np.array([max(r[p_key]["delta_e2000_mean"], floor) for r in mine])
            y = np.array([max(r[s_key]["delta_e2000_mean"], floor) for r in mine])
            reach = np.array([bool(r["strauss"].get("out_of_reach", False)) for r in mine])
            line = ax.scatter(x[~reach], y[~reach], s=18, label=f"{label} ({len(mine)})")
            if reach.any():
                ax.scatter(x[reach], y[reach], s=30, marker="x", color=line.get_facecolor()[0])
        ax.plot([floor, top], [floor, top], color="grey", lw=0.8)
        ax.axvline(1.0, color="grey", lw=0.6, ls=":")
        ax.axhline(1.0, color="grey", lw=0.6, ls=":")
        ax.set(xscale="log", yscale="log", xlabel="Phong: mean CIEDE2000 (largest over the scenes)", title=title)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("Strauss: mean CIEDE2000")
    axes[0].legend(fontsize=8, title="× : Strauss out of reach", title_fontsize=8)
    return {MERL_FIGURE: png_bytes(fig, DPI)}


def _held_out_phrase(holdout: str) -> str:
    text = str(holdout).strip()
    if text.isdigit():
        k = int(text)
        return f"images {k}, {2 * k}, {3 * k}, …"
    return f"images {text}"


def _rgb(values: list[float]) -> str:
    return "(" + ", ".join(f"{v:.3g}" for v in values) + ")"


def add_sections(doc: Document, study: dict[str, Any], images: dict[str, bytes]) -> None:
    """Sections 5 and 6 (for the parts the study ran) appended to ``doc``."""
    if "merl" in study:
        _merl_section(doc, study["merl"], images)
    if "capture" in study:
        _capture_section(doc, study["capture"])


def _merl_section(doc: Document, m: dict[str, Any], images: dict[str, bytes]) -> None:
    """Section 5: how the measured materials were rendered, fitted and judged; the shares
    matched by class and by scene, the figure, and one row per material."""
    doc.heading("5. Expressiveness on measured materials (MERL, Ngan et al. 2005)")
    doc.para(
        f"{len(m['materials'])} materials of {m['source']} ('{m['fits']}': kd/π plus bbm's NganCookTorrance, "
        f"formulas of bbm commit {m['bbm_commit'][:12]}), each rendered under {', '.join(m['scenes'])} at "
        f"{m['image_size']}×{m['image_size']} px ({m['supersample']}×{m['supersample']} points per fully covered "
        "pixel), then fitted by Strauss (single-target fit) and Phong (capture fitter, lights known) by least "
        "squares on the same pixels: to the radiance as rendered; clipped at white (pixels brighter than the "
        "ΔE metric's white left out of both fits, as a camera exposed for the sphere saturates them, and the "
        "fit judged on every pixel); and by Strauss with its default loss (a robust refit when the least-squares "
        "fit visibly misses). ΔE: mean CIEDE2000 over the sphere, the largest over the scenes; matched: ΔE ≤ "
        f"{m['jnd']:g}. Out of reach: Strauss's fit to the radiance warns highlight-out-of-reach, or pins the "
        "colour at 1 or s at a bound with the highlight holding the residual. Classes by name keyword: "
        + "; ".join(f"{label}: {', '.join(words)}" for label, words in m["class_keywords"].items())
        + "; the rest: other."
    )
    _merl_class_tables(doc, m)
    _merl_scene_table(doc, m)
    study_figure(
        doc,
        images,
        MERL_FIGURE,
        "Each measured material's ΔE under Strauss against Phong, as rendered and clipped at white (log scales; "
        "dotted: one JND; ×: Strauss out of reach).",
    )
    _merl_material_table(doc, m)


def _matched_pair(entry: dict[str, Any] | None) -> str:
    """A group's share matched and median ΔE under one fit, as one cell."""
    entry = entry or {}
    return f"{_pct(entry.get('matched'))}, {_num(entry.get('median_delta_e'))}"


def _merl_class_tables(doc: Document, m: dict[str, Any]) -> None:
    """The two tables by class (and all materials): as rendered, then clipped at white and
    with Strauss's default loss."""
    groups = [(label, m["by_class"][label]) for label in CLASSES] + [("all", m["all"])]
    groups = [(label, c) for label, c in groups if c["materials"]]
    rows = []
    for label, c in groups:
        s, p = c["strauss"], c["phong"]
        rows.append(
            [
                label,
                str(c["materials"]),
                _pct(s["matched"]),
                _num(s["median_delta_e"]),
                _pct(s["out_of_reach"]),
                _pct(p["matched"]),
                _num(p["median_delta_e"]),
                _pct(c["strauss_better"]),
            ]
        )
    doc.para("As rendered (least squares to the radiance):")
    study_table(
        doc,
        [
            "class",
            "materials",
            "Strauss: ΔE ≤ 1",
            "Strauss: median ΔE",
            "Strauss: out of reach",
            "Phong: ΔE ≤ 1",
            "Phong: median ΔE",
            "Strauss closer",
        ],
        rows,
    )
    rows = [
        [
            label,
            _matched_pair(c.get("strauss_clipped")),
            _matched_pair(c.get("phong_clipped")),
            _pct(c.get("strauss_better_clipped")),
            _matched_pair(c.get("strauss_default")),
        ]
        for label, c in groups
    ]
    doc.para("Clipped at white (both by least squares), and Strauss with its default loss (ΔE ≤ 1, median ΔE):")
    study_table(
        doc,
        ["class", "clipped: Strauss", "clipped: Phong", "clipped: Strauss closer", "Strauss, default loss"],
        rows,
    )


def _merl_scene_table(doc: Document, m: dict[str, Any]) -> None:
    """The table by scene: each fit's share matched and median ΔE, Strauss's share out of reach."""
    rows = []
    for name, c in m["by_scene"].items():
        rows.append(
            [
                name,
                _matched_pair(c["strauss"]),
                _pct(c["strauss"]["out_of_reach"]),
                _matched_pair(c["phong"]),
                _matched_pair(c.get("strauss_clipped")),
                _matched_pair(c.get("phong_clipped")),
            ]
        )
    study_table(
        doc,
        ["scene", "Strauss", "Strauss: out of reach", "Phong", "clipped: Strauss", "clipped: Phong"],
        rows,
    )


def _delta_e_cell(entry: dict[str, Any] | None) -> str:
    """One fit's ΔE of a material, its error when it failed, nothing when it did not run."""
    if not entry:
        return ""
    return _num(entry["delta_e2000_mean"]) if entry["status"] == "ok" else f"error: {entry['message']}"


def _merl_material_table(doc: Document, m: dict[str, Any]) -> None:
    """One row per measured material, by class and name: its Cook–Torrance parameters and
    every fit's ΔE."""
    rows = []
    for r in sorted(m["materials"], key=lambda r: (CLASSES.index(r["class"]), r["name"])):
        s = r["strauss"]
        clipped = max((scene.get("clipped_pixels", 0) for scene in r.get("scenes", {}).values()), default=0)
        rows.append(
            [
                r["name"],
                r["class"],
                _rgb(r["kd"]),
                _rgb(r["ks"]),
                f"{r['f0']:.3g}",
                f"{r['roughness']:.3g}",
                _delta_e_cell(s),
                ("yes" if s["out_of_reach"] else "no") if s["status"] == "ok" else "",
                _delta_e_cell(r["phong"]),
                str(clipped),
                _delta_e_cell(r.get("strauss_clipped")),
                _delta_e_cell(r.get("phong_clipped")),
                _delta_e_cell(r.get("strauss_default")),
            ]
        )
    study_table(
        doc,
        [
            "material",
            "class",
            "kd",
            "ks",
            "F0",
            "m",
            "Strauss ΔE",
            "out of reach",
            "Phong ΔE",
            "pixels above white",
            "clipped: Strauss ΔE",
            "clipped: Phong ΔE",
            "Strauss ΔE, default loss",
        ],
        rows,
    )


def _capture_section(doc: Document, c: dict[str, Any]) -> None:
    """Section 6: the capture, how the models were fitted and checked, and one row per
    model (its fit and held-out error, verdict, stability over two halves and time)."""
    doc.heading("6. Real photographs: held-out error and stability of every model")
    doc.para(
        f"{c['source']}: {c['pixels']} sphere pixels × {c['images']} images. Each model is fitted to "
        f"{c['fitted_images']} images and predicts the {c['held_out_images']} others (held out: "
        f"{_held_out_phrase(c['holdout'])}); its lobe parameters are fitted again on two disjoint halves of the "
        "fitted images (odd and even), stable when each half's value lies within the other's perceptual "
        "equivalence range."
    )
    rows = []
    for name, e in c["models"].items():
        if e["status"] != "ok":
            rows.append([name, f"error: {e['message']}", "", "", "", "", ""])
            continue
        rows.append(
            [
                name,
                _num(e["fit"]["delta_e2000_mean"]),
                _num(e["held_out"]["delta_e2000_mean"]),
                _num(e["held_out"]["relative_rms"]),
                str(e["fit"].get("verdict")),
                _stability_phrase(e)
                or (
                    f"error: {e['stability']['message']}"
                    if e.get("stability")
                    else "n/a (no parameter compared for this model)"
                ),
                f"{e['time_s']:.0f}",
            ]
        )
    study_table(
        doc,
        ["model", "fit ΔE", "held-out ΔE", "held-out relative RMS", "verdict", "halves (odd / even)", "time (s)"],
        rows,
    )


# --- writing ----------------------------------------------------------------------------------


def study_markdown_document(
    study: dict[str, Any], verdicts: list[dict[str, Any]], images: dict[str, bytes]
) -> Document:
    """The whole report as a `Document`: the four
    parts, then sections 5 and 6, then the timing line."""
    doc = study_document(study, verdicts, images)
    timing = doc.blocks.pop()  # the timing line stays last
    add_sections(doc, study, images)
    doc.blocks.append(timing)
    return doc


def write_study_report(study: dict[str, Any], outdir: str | Path, *, force: bool = False) -> list[Path]:
    """Write study.json, study.md, study.html and the PNG plots into ``outdir`` (created if
    missing; its parent must exist), all or none, as
    `strauss_fit.reporting.study_report.write_report` does, with sections 5 and 6
    and their verdicts when the study has them."""
    return write_study_files(
        study,
        outdir,
        report_files(study),
        all_conclusions,
        lambda data: {**plots(data), **real_plots(data)},
        study_markdown_document,
        force=force,
    )


def check_study_outputs(outdir: str | Path, force: bool, *, merl: bool = False) -> None:
    """Refuse early (before the study runs) if the outputs exist and ``force`` is not set."""
    check_outputs(outdir, force, report_files(merl=merl))

"""The one HTML and Markdown document builder of every report.

A `Document` collects headings, paragraphs, bullet lists, tables and images, and
renders them as Markdown (images linked from a folder, or beside the page) and as one
self-contained HTML page (images embedded as base64 PNG, no scripts, no network). The fit
report (`strauss_fit.reporting.fit_report`), the capture's report
(`strauss_fit.reporting.capture_report`) and the study report
(`strauss_fit.reporting.study_report`) all build theirs with it, and the blocks the
first two share (the verdict and its warnings, the held parameters, a correlation table,
the posterior's columns, number formats) are here once.

Text quoted from input files (a fit result's warnings and notes, a material's name, a
title) reaches both renderings: the HTML escapes it (`html.escape`), and the Markdown
(`markdown_text`) keeps it on its line and inert — a line break becomes a space (a
newline in a warning would end a table row or start a heading), a control character is
shown as ``\\x1b``, and a ``<`` that would open an HTML tag is escaped, so that no viewer
of REPORT.md renders markup the report did not write. The report's own Markdown
(``**bold**``, backquoted code) is left as it is.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._escaping import escape
from ..errors import StraussFitError

_LINE_BREAKS = re.compile(r"\r\n|[\n\r\x0b\x0c\x85\u2028\u2029]")
_TAG_START = re.compile(r"<(?=[A-Za-z/!?])")


def markdown_text(text: str) -> str:
    """``text`` as inert Markdown on one line (see the module): line breaks as spaces,
    control characters as ``\\xNN``/``\\uNNNN`` (`strauss_fit._escaping.escape`), ``<``
    before a tag name as ``\\<``."""
    return _TAG_START.sub("\\<", escape(_LINE_BREAKS.sub(" ", text)))


@dataclass
class _Block:
    kind: str  # "heading", "para", "bullets", "table", "image"
    text: str = ""
    level: int = 2
    css: str | None = None
    items: list[str] = field(default_factory=list)
    header: list[str] = field(default_factory=list)
    rows: list[list[str]] = field(default_factory=list)
    name: str = ""
    caption: bool = False
    escape_header: bool = True


class Document:
    """A report's content, rendered by `markdown` and `html`.

    ``assets``: the folder (relative to the Markdown file) its images are linked from;
    empty for images beside it. `images` holds the PNGs by file name.
    """

    def __init__(self, assets: str = ""):
        self.assets = assets
        self.blocks: list[_Block] = []
        self.images: dict[str, bytes] = {}

    def heading(self, text: str, level: int = 2) -> None:
        self.blocks.append(_Block("heading", text, level=level))

    def para(self, text: str, css: str | None = None) -> None:
        """A paragraph; ``css`` is an HTML class (``ok``, ``bad``, ``warn`` in the fit report's style)."""
        self.blocks.append(_Block("para", text, css=css))

    def bullets(self, items: Sequence[str], css: str | None = None) -> None:
        """A bullet list (nothing for no items)."""
        if items:
            self.blocks.append(_Block("bullets", css=css, items=list(items)))

    def table(self, header: Sequence[str], rows: Sequence[Sequence[object]], *, escape_header: bool = True) -> None:
        """A table; in the Markdown a ``|`` in a cell is escaped, in the header only with
        ``escape_header``."""
        self.blocks.append(
            _Block(
                "table",
                header=[str(h) for h in header],
                rows=[[str(c) for c in row] for row in rows],
                escape_header=escape_header,
            )
        )

    def image(self, name: str, png: bytes | None, alt: str, *, caption: bool = False) -> None:
        """A PNG named ``name`` with its description ``alt``. ``caption``: the Markdown
        also prints ``alt`` below the image and links it even when ``png`` is None (a
        figure written beside the page by other means); otherwise a missing PNG is left
        out. HTML shows only the PNGs given."""
        if png is None and not caption:
            return
        if png is not None:
            self.images[name] = png
        self.blocks.append(_Block("image", alt, name=name, caption=caption))

    # --- rendering ----------------------------------------------------------------------

    def markdown(self) -> str:
        """The Markdown text: blocks separated by blank lines, ending with a newline."""
        return "\n\n".join(self._markdown_block(block) for block in self.blocks) + "\n"

    def _markdown_block(self, block: _Block) -> str:
        text = markdown_text(block.text)
        if block.kind == "heading":
            return "#" * block.level + " " + text
        if block.kind == "para":
            return text
        if block.kind == "bullets":
            return "\n".join(f"- {markdown_text(item)}" for item in block.items)
        if block.kind == "table":

            def cell(text: str) -> str:
                return markdown_text(text).replace("|", "\\|")

            header = [cell(h) if block.escape_header else markdown_text(h) for h in block.header]
            lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(block.header)]
            lines += ["| " + " | ".join(cell(c) for c in row) + " |" for row in block.rows]
            return "\n".join(lines)
        path = f"{self.assets}/{block.name}" if self.assets else block.name
        link = f"![{text}]({path})"
        return f"{link}\n\n*{text}*" if block.caption else link

    def html(self, title: str, style: str, *, spaced: bool = False) -> str:
        """The self-contained HTML page titled ``title`` with the CSS ``style``; ``spaced``
        puts the body's elements on lines of their own after the doctype."""
        body = [part for part in (self._html_block(block) for block in self.blocks) if part is not None]
        gap = "\n" if spaced else ""
        return (
            f'<!DOCTYPE html>{gap}<html lang="en"><head><meta charset="utf-8">'
            f"<title>{html.escape(title)}</title><style>{style}</style></head><body>{gap}"
            + "\n".join(body)
            + f"{gap}</body></html>\n"
        )

    def _html_block(self, block: _Block) -> str | None:
        e = html.escape
        css = f' class="{block.css}"' if block.css else ""
        if block.kind == "heading":
            return f"<h{block.level}>{e(block.text)}</h{block.level}>"
        if block.kind == "para":
            return f"<p{css}>{e(block.text)}</p>"
        if block.kind == "bullets":
            return f"<ul{css}>" + "".join(f"<li>{e(item)}</li>" for item in block.items) + "</ul>"
        if block.kind == "table":
            head = "".join(f"<th>{e(h)}</th>" for h in block.header)
            rows = "".join("<tr>" + "".join(f"<td>{e(c)}</td>" for c in row) + "</tr>" for row in block.rows)
            return f"<table><thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>"
        png = self.images.get(block.name)
        if png is None:
            return None
        data = base64.b64encode(png).decode("ascii")
        return (
            f'<figure><img alt="{e(block.text)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{e(block.text)}</figcaption></figure>"
        )


# --- blocks the fit report and the capture's report share -----------------------------------


def fmt(value: float | None, digits: int = 4) -> str:
    """``value`` to ``digits`` significant digits, or "–" for a missing or non-finite one."""
    if value is None or not np.isfinite(value):
        return "–"
    return f"{value:.{digits}g}"


def value_text(value: Any) -> str:
    """A recorded value as a cell: a vector as "(a, b, c)", a number by `fmt`."""
    if isinstance(value, (list, tuple)):
        return "(" + ", ".join(f"{float(v):.4g}" for v in value) + ")"
    return fmt(value) if value is not None else "–"


def range_text(low: float | None, high: float | None) -> str:
    """A range of values (an equivalence band) as "low – high", three significant digits."""
    return f"{fmt(low, 3)} – {fmt(high, 3)}"


def prior_text(low: float | None, high: float | None) -> str:
    """A uniform prior's box as "[low, high]", three significant digits."""
    return f"[{fmt(low, 3)}, {fmt(high, 3)}]"


def generated_by() -> str:
    """The sentence that dates a report: the strauss-fit version and the time it was built."""
    from .._version import __version__

    stamp = _dt.datetime.now().strftime("%Y-%m-%d %H:%M")
    return f"Generated by strauss-fit {__version__} on {stamp}."


def untrustworthy_chain(reasons: Sequence[str]) -> str:
    """The warning a report puts first when its chain's diagnostics fail, with their reasons."""
    return "The chain is not trustworthy yet: " + "; ".join(reasons) + "."


def verdict_and_warnings(
    doc: Document, heading: str, verdict: str | None, verdict_text: str, warnings: Sequence[str], none_text: str
) -> None:
    """The section a reader must not miss, first in a fit's report: ``heading``, the fit's
    verdict in one paragraph coloured by what it says (``ok`` when consistent, ``bad`` on a
    mismatch), then the warnings as a list, or ``none_text`` when there are none."""
    doc.heading(heading)
    if verdict:
        doc.para(verdict_text, "ok" if verdict == "consistent" else "bad" if verdict == "mismatch" else None)
    if warnings:
        doc.bullets(warnings, "warn")
    else:
        doc.para(none_text, "ok")


def held_parameters(doc: Document, held: dict[str, Any]) -> None:
    """The sub-section of the parameters a fit held: each one's value and why it was held."""
    doc.heading("Held parameters", 3)
    doc.table(
        ["parameter", "value", "why"],
        [
            [str(name), value_text((info or {}).get("value")), str((info or {}).get("reason", ""))]
            for name, info in held.items()
        ],
    )


def correlation_table(doc: Document, labels: Sequence[str], corr: np.ndarray) -> None:
    """A correlation matrix as a table, the labels as the first row and column, two decimals."""
    doc.table([""] + list(labels), [[label] + [f"{v:+.2f}" for v in corr[i]] for i, label in enumerate(labels)])


#: The keys of a posterior summary's percentiles, in the order of their columns.
PERCENTILES = ("median", "p16", "p84", "p2.5", "p97.5")


def posterior_header(name: str) -> list[str]:
    """The posterior's columns of a parameter table, ``name`` saying which posterior."""
    return [f"median ({name})", "16 %", "84 %", "2.5 %", "97.5 %", "prior"]


def posterior_cells(percentiles: dict[str, Any]) -> list[str]:
    """One parameter's median and percentiles (a posterior summary's entry) as cells; the
    prior's cell follows them (`prior_text`)."""
    return [fmt(percentiles[key]) for key in PERCENTILES]


#: The suffixes of a report file (the reports are HTML, their Markdown twin written beside).
HTML_SUFFIXES = (".html", ".htm")


def check_html_name(path: Any) -> None:
    """Refuse a report name that is not HTML, in one line, before any work."""
    if Path(path).suffix.lower() not in HTML_SUFFIXES:
        raise StraussFitError(f"the report is HTML: give -o a .html name, got {path}")

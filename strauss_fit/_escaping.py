"""Showing text quoted from input files without letting it act: control characters as
``\\x1b`` (one home for the command line's messages and the reports' Markdown)."""

from __future__ import annotations

import re

# C0 and C1 controls, the Unicode line and paragraph separators, and the bidirectional
# embeddings, overrides and isolates (U+202A-U+202E, U+2066-U+2069: a name holding U+202E
# would print the rest of its line reversed)
_CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f\u2028-\u202e\u2066-\u2069]")
_CONTROL_AND_NEWLINES = re.compile(r"[\x00-\x1f\x7f-\x9f\u2028-\u202e\u2066-\u2069]")
#: Every character `escape` (with ``newlines``) shows escaped: what a name written into a
#: file must not hold (`strauss_fit.io.material_tables`).
CONTROL_CHARACTERS = _CONTROL_AND_NEWLINES


def _escaped(match: re.Match) -> str:
    code = ord(match.group())
    return {9: "\\t", 10: "\\n", 13: "\\r"}.get(code) or (f"\\x{code:02x}" if code < 256 else f"\\u{code:04x}")


def escape(text: str, *, newlines: bool = False) -> str:
    """``text`` with control characters (an ESC sequence in a material name, say) shown as
    ``\\x1b``; with ``newlines`` also tab, CR and LF (for one-line messages)."""
    return (_CONTROL_AND_NEWLINES if newlines else _CONTROL).sub(_escaped, text)

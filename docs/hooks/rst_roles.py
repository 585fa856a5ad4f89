"""MkDocs hook: tidy the reStructuredText idioms left in docstrings on the API pages.

The library's docstrings use Sphinx roles (``:func:`fit```, ``:math:`\\cos\\alpha```),
``.. math::`` directives, ``Example::`` literal markers and simple RST tables. mkdocstrings
renders docstrings as Markdown, where these appear verbatim (":func:" before the code).
This hook runs on the rendered HTML of the pages under ``api/`` and

- drops the role prefix before inline code (``:func:<code>fit</code>`` -> ``<code>fit</code>``)
  and the ``~`` of shortened references (``~a.b.C`` -> ``C``);
- drops the ``.. math::`` line (the formula itself is already a code block below it) and
  turns a trailing ``::`` into ``:``;
- shows paragraphs that are RST tables (lines of ``=``) preformatted.

It changes nothing outside ``api/`` and nothing in the sources.
"""

from __future__ import annotations

import re

_ROLE = re.compile(r":(?:py:)?(?:math|func|class|meth|mod|data|attr|obj|exc|const|ref|term|doc):(?=<code>)")
_TILDE = re.compile(r"<code>~([\w.]+)</code>")
_MATH_DIRECTIVE = re.compile(r"<p>\.\. math::</p>\s*")
_LITERAL_MARKER = re.compile(r"(\w)::</p>")
_RST_TABLE = re.compile(r"<p>(=+(?: +=+)+\n.*?)</p>", re.DOTALL)


def _short(match: re.Match) -> str:
    return f"<code>{match.group(1).rsplit('.', 1)[-1]}</code>"


def on_page_content(html: str, page, config, files) -> str:  # noqa: ARG001 (MkDocs hook signature)
    if not page.file.src_uri.startswith("api/"):
        return html
    html = _ROLE.sub("", html)
    html = _TILDE.sub(_short, html)
    html = _MATH_DIRECTIVE.sub("", html)
    html = _LITERAL_MARKER.sub(r"\1:</p>", html)
    html = _RST_TABLE.sub(r'<pre class="rst-table">\1</pre>', html)
    return html

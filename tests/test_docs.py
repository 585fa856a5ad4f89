"""The documentation: the MkDocs site builds with ``--strict``, and README.md stays a short
front door whose relative links all point at files in the repository."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path
from urllib.parse import unquote

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
README_LIMIT = 12_000

# Markdown links and images: [text](target) / ![alt](target), with an optional "title".
_LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
# Reference-style definitions: [label]: target
_DEFINITION = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s|$)", re.MULTILINE)
_FENCE = re.compile(r"^(```|~~~).*?^\1", re.MULTILINE | re.DOTALL)


def _relative_links(markdown: str) -> list[str]:
    """Every link target in ``markdown`` outside code blocks that is a relative path
    (no scheme such as ``https:``/``mailto:``, not a bare ``#anchor``), without its anchor."""
    text = _FENCE.sub("", markdown)
    text = re.sub(r"`[^`\n]*`", "", text)  # inline code
    targets = _LINK.findall(text) + _DEFINITION.findall(text)
    links = []
    for target in targets:
        if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target) or target.startswith(("#", "//")):
            continue
        path = unquote(target.split("#", 1)[0].split("?", 1)[0])
        if path:
            links.append(path)
    return links


def test_readme_is_short() -> None:
    size = len(README.read_text(encoding="utf-8"))
    assert size < README_LIMIT, f"README.md has {size} characters; keep it under {README_LIMIT} (move detail to docs/)"


def test_readme_relative_links_exist() -> None:
    links = _relative_links(README.read_text(encoding="utf-8"))
    assert links, "README.md links into docs/"
    missing = [link for link in links if not (README.parent / link).exists()]
    assert not missing, f"README.md links to files that do not exist: {missing}"


def test_link_finder() -> None:
    text = (
        '[a](docs/a.md) ![b](docs/b.png "title") [c](https://example.org) [d](#top) '
        "[e](docs/e.md#part) `[f](no.md)`\n```\n[g](no.md)\n```\n[h]: docs/h.md\n"
    )
    assert _relative_links(text) == ["docs/a.md", "docs/b.png", "docs/e.md", "docs/h.md"]


def test_site_builds_strictly(tmp_path: Path) -> None:
    """``mkdocs build --strict``: every warning (a broken link or anchor, a page left out of
    the navigation, a docstring the API reference cannot render) fails the build. The
    documentation tools are in the ``test`` extra; this test is not skipped without them."""
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, f"mkdocs build --strict failed:\n{result.stdout}\n{result.stderr}"
    assert (tmp_path / "site" / "index.html").is_file()

"""The project's own rules: the code is formatted and linted by ruff (configured in
pyproject.toml), so CI, which runs the test suite, enforces both."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _ruff(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ruff", *args], cwd=ROOT, capture_output=True, text=True)


def test_ruff_lint_passes():
    result = _ruff("check", ".")
    assert result.returncode == 0, result.stdout + result.stderr


def test_ruff_format_is_applied():
    result = _ruff("format", "--check", ".")
    assert result.returncode == 0, result.stdout + result.stderr


def test_every_package_folder_is_installed():
    """pyproject.toml lists the packages one by one (``cli/`` is installed as
    ``strauss_fit_cli``): a new subpackage left off the list works in an editable install
    and is missing from a wheel."""
    import tomllib

    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(config["packages"])
    where = {name: ROOT / folder for name, folder in config["package-dir"].items()}
    found = set()
    for top, folder in where.items():
        for init in folder.rglob("__init__.py"):
            parts = init.parent.relative_to(folder).parts
            found.add(".".join((top, *parts)))
    assert listed == found, {"not installed": sorted(found - listed), "not a package": sorted(listed - found)}


def test_docstrings_are_markdown_not_restructured_text():
    """The API pages render docstrings as Markdown (Google style, mkdocs.yml) with no
    rewriting hook: a Sphinx role (``:func:`x```) or directive would show verbatim."""
    import re

    rst = re.compile(r":(?:py:)?(?:func|class|meth|mod|data|attr|obj|exc|const|math|ref):`|^\s*\.\. [a-z]+::", re.M)
    offenders = []
    for folder in ("strauss_fit", "cli", "data_synth"):
        for path in (ROOT / folder).rglob("*.py"):
            for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
                if rst.search(line):
                    offenders.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert not offenders, "\n".join(offenders[:20])

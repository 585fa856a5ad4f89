"""The examples in the public API's docstrings run, and print what they say (doctest).

Every name of the package's face (``strauss_fit.__all__``) whose docstring holds an
example is checked, from the repository's root (the examples read the bundled scenes);
the main entry points must have one."""

from __future__ import annotations

import doctest
import inspect
from pathlib import Path

import pytest

import strauss_fit as sf

ROOT = Path(__file__).resolve().parents[1]
#: The entry points a user meets first: each must show an example.
MUST_HAVE_EXAMPLES = {"fit", "render", "load_scene", "Material", "fresnel", "shadow", "float64", "phong_to_strauss"}


def _examples() -> dict[str, doctest.DocTest]:
    finder = doctest.DocTestFinder(recurse=False)
    found = {}
    for name in sf.__all__:
        obj = getattr(sf, name)
        if not (inspect.isfunction(obj) or inspect.isclass(obj)):
            continue
        tests = [test for test in finder.find(obj, name, globs={}) if test.examples]
        if tests:
            found[name] = tests[0]
    return found


EXAMPLES = _examples()


def test_the_main_entry_points_show_an_example():
    assert MUST_HAVE_EXAMPLES <= set(EXAMPLES), sorted(MUST_HAVE_EXAMPLES - set(EXAMPLES))


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_the_example_runs_as_written(name, monkeypatch):
    monkeypatch.chdir(ROOT)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    out: list[str] = []
    result = runner.run(EXAMPLES[name], out=out.append)
    assert result.failed == 0, "".join(out)

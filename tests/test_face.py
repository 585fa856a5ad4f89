"""The package's face (``strauss_fit/__init__.py``): every public name listed once in
``_PUBLIC``, the same re-exports stated for type checkers, imported on first use."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import strauss_fit as sf

INIT = Path(sf.__file__)


def _type_checking_reexports() -> dict[str, str]:
    """name -> relative module, from the ``if TYPE_CHECKING:`` block's ``from .m import X as X``."""
    found = {}
    for node in ast.parse(INIT.read_text()).body:
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for stmt in node.body:
                assert isinstance(stmt, ast.ImportFrom), ast.unparse(stmt)
                for alias in stmt.names:
                    assert alias.asname == alias.name, f"{alias.name}: re-export as 'X as X'"
                    found[alias.name] = "." * stmt.level + (stmt.module or "")
    return found


def test_the_type_checking_reexports_are_the_lazy_names():
    assert _type_checking_reexports() == sf._LAZY


def test_every_public_name_is_the_object_of_its_module():
    import importlib

    for name in sf.__all__:
        module = importlib.import_module(sf._LAZY[name], "strauss_fit") if name in sf._LAZY else sf
        assert getattr(module, name) is getattr(sf, name), name


def test_the_functions_keep_their_names_beside_the_subpackages():
    """``strauss_fit.fit`` is the function whatever is imported: the subpackage is ``fitting``."""
    import strauss_fit.fitting.api
    import strauss_fit.rendering.strauss  # noqa: F401

    assert callable(sf.fit) and sf.fit.__module__ == "strauss_fit.fitting.api"
    assert callable(sf.render) and sf.render.__module__ == "strauss_fit.rendering.strauss"


def test_importing_the_package_loads_no_jax_and_sets_no_environment():
    code = (
        "import os, sys; before = dict(os.environ); import strauss_fit; "
        "print('jax' in sys.modules, dict(os.environ) == before)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.split() == ["False", "True"]

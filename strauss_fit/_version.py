"""strauss-fit's version: one home, read by the package face, reports and run keys
(kept equal to ``pyproject.toml``'s ``version``, which ``tests/test_project.py`` checks)."""

__version__ = "0.1.0"

"""The Strauss evaluator's modes and table size: importable without JAX (the command line
names them in its help, which must not load JAX). `strauss_fit.models.strauss`
implements them."""

from __future__ import annotations

from typing import Literal

Mode = Literal["exact", "table", "j-table"]
MODES: tuple[str, ...] = ("exact", "table", "j-table")
#: Default number of samples of the F/G tables over [0, pi/2] (``mode="table"``) and per
#: axis of the j(alpha, gamma) table (``mode="j-table"``).
DEFAULT_TABLE_SIZE = 1024

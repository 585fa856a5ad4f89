"""The chain file's layout: the names of its two HDF5 groups, the format it declares, the
metadata group's writer, and `ChainError`.

Why a module of its own: the in-memory backend (`._backends`) writes the metadata
group and the chain file's reader (`._chain`) checks it, and the reader also writes
through the backend; both take the layout from here so that neither imports the other
both ways.
"""

from __future__ import annotations

import json
from typing import Any

import h5py

from ...errors import StraussFitError

#: emcee's group: ``chain`` (S, W, P), ``log_prob`` (S, W), ``accepted`` (W,), the random state.
CHAIN_GROUP = "mcmc"
#: strauss-fit's group: what a report or a resume needs, as one JSON attribute.
META_GROUP = "strauss_fit"
FORMAT = "strauss-fit chain"
FORMAT_VERSION = 1


class ChainError(StraussFitError):
    """A chain file is missing, unreadable, foreign, or does not match the request."""


def write_metadata_group(f: h5py.File, meta: dict[str, Any]) -> None:
    """Create or replace the ``strauss_fit`` group of the open file ``f``: the format, its
    version, and ``meta`` as JSON (NaN refused: the file must stay readable as JSON)."""
    if META_GROUP in f:
        del f[META_GROUP]
    g = f.create_group(META_GROUP)
    g.attrs["format"] = FORMAT
    g.attrs["format_version"] = FORMAT_VERSION
    g.attrs["metadata"] = json.dumps(meta, allow_nan=False)

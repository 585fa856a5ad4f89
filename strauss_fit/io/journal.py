"""An append-only, crash-safe progress file: what a long batch has finished so far.

The file is JSON Lines: the first line a header naming the work (``format``, ``version``
and a ``key`` that identifies the inputs and settings), then one line per finished item.
Each append is one write of whole lines followed by ``fsync``; a failed append (a full
disk) truncates the file back to where it was, so it never ends in a partial line that
this process wrote. A process killed in the middle of an append can still leave a partial
last line: `Journal.open` drops it (and truncates it away) when resuming.

Used by the conversions (``phong2strauss``/``strauss2phong --resume``): the results are
appended as they complete, and the final output is written atomically at the end, after
which the progress file is removed.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

from ..errors import StraussFitError
from . import files
from .files import WriteError, os_error_message

FORMAT = "strauss-fit progress"
VERSION = 1


def run_key(description: Any) -> str:
    """The SHA-256 digest that identifies a run's results: ``description`` (everything
    that decides them, as JSON with sorted keys: input digests, scene, settings) together
    with strauss-fit's version. Equal keys mean the same results; resuming work under
    another key would mix results of two configurations. The one place run keys are made
    (conversions' progress files, the results of a folder fit)."""
    from .._version import __version__

    text = json.dumps({"run": description, "strauss_fit": __version__}, sort_keys=True, allow_nan=False, default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def file_digest(path: str | Path) -> str:
    """The SHA-256 digest of a file's bytes (read in chunks; OSError if unreadable)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while chunk := handle.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()


def pytree_digest(tree: Any) -> str:
    """The SHA-256 digest of a pytree's structure and leaves (an in-memory scene or
    target): arrays by dtype, shape and bytes, other leaves by their text."""
    import jax
    import numpy as np

    leaves, treedef = jax.tree_util.tree_flatten(tree)
    digest = hashlib.sha256(str(treedef).encode("utf-8"))
    for leaf in leaves:
        if hasattr(leaf, "shape") and hasattr(leaf, "dtype"):
            array = np.ascontiguousarray(np.asarray(leaf))
            digest.update(f"{array.dtype}{array.shape}".encode())
            digest.update(array.tobytes())
        else:
            digest.update(repr(leaf).encode("utf-8"))
    return digest.hexdigest()


class JournalError(StraussFitError):
    """A progress file is missing, damaged or belongs to other work."""


class Journal:
    """The progress file ``path`` of the work identified by ``key`` (a string)."""

    def __init__(self, path: str | Path, key: str):
        self.path = Path(path)
        self.key = key
        self.records: list[dict[str, Any]] = []
        self._started = False

    @property
    def exists(self) -> bool:
        return self.path.exists()

    def open(self) -> list[dict[str, Any]]:
        """Read the records of an existing progress file of this work (to resume), dropping
        a partial last line. One-line errors for a file of other work or a damaged one."""
        try:
            data = self.path.read_bytes()
        except OSError as exc:
            raise JournalError(f"cannot read the progress file {self.path}: {exc.strerror or exc}") from None
        lines = data.split(b"\n")
        complete = lines[:-1]  # the text after the last newline is a partial line (or empty)
        try:
            header = json.loads(complete[0]) if complete else None
        except (ValueError, UnicodeDecodeError):
            header = None
        if not isinstance(header, dict) or header.get("format") != FORMAT:
            raise JournalError(
                f"{self.path} is not a strauss-fit progress file (remove it, or start again with --force)"
            )
        if header.get("version") != VERSION or header.get("key") != self.key:
            raise JournalError(
                f"{self.path} is the progress of another run (other inputs or settings): "
                "resume with the same inputs and options, or start again with --force"
            )
        records = []
        good = len(complete[0]) + 1
        for line in complete[1:]:
            try:
                record = json.loads(line)
            except (ValueError, UnicodeDecodeError):
                break
            if not isinstance(record, dict):
                break
            records.append(record)
            good += len(line) + 1
        if good < len(data):  # a partial line from a killed append
            try:
                os.truncate(self.path, good)
            except OSError as exc:
                raise WriteError(os_error_message(exc, self.path)) from None
        self.records = records
        self._started = True
        return records

    def append(self, records: list[dict[str, Any]]) -> None:
        """Append records (the header first, on the first append of a new file)."""
        if not records:
            return
        text = "".join(json.dumps(r, allow_nan=False, separators=(",", ":")) + "\n" for r in records)
        if not self._started:
            header = {"format": FORMAT, "version": VERSION, "key": self.key}
            text = json.dumps(header) + "\n" + text
        try:
            files._append_file(self.path, text.encode("utf-8"))
        except OSError as exc:
            raise WriteError(os_error_message(exc, self.path)) from None
        self._started = True
        self.records += records

    def remove(self) -> None:
        self.path.unlink(missing_ok=True)

"""Writing files safely, and reading JSON with one-line errors.

Every write is atomic (a temporary file in the same folder, then a rename), and an existing
file is never overwritten unless ``force`` is true. The image writer
(:func:`strauss_fit.io.images.write_image`) goes through the same machinery.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..errors import ImageError, OutputExistsError, StraussFitError


def check_writable(path: str | Path, force: bool) -> Path:
    """Refuse an existing output without ``force`` and a missing parent folder."""
    path = Path(path)
    if path.is_dir():
        raise ImageError(f"output path is a directory: {path}")
    if path.exists() and not force:
        raise OutputExistsError(f"output {path} exists; pass --force to overwrite it")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise ImageError(f"output folder does not exist: {parent}")
    if not os.access(parent, os.W_OK):
        raise ImageError(f"output folder is not writable: {parent}")
    return path


def write_atomic(path: Path, write: Callable[[Path], None]) -> None:
    """Call ``write(tmp_path)`` on a temporary sibling of ``path``, then rename it over
    ``path``; the temporary file is removed if anything fails."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix, dir=path.parent or ".")
    os.close(fd)
    try:
        write(Path(tmp))
        # mkstemp creates the file owner-only; give the result the usual umask permissions
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_bytes(path: str | Path, data: bytes, *, force: bool = False) -> Path:
    """Write bytes (e.g. an encoded PNG) atomically (refusing to overwrite without ``force``)."""
    path = check_writable(path, force)
    write_atomic(path, lambda tmp: tmp.write_bytes(data))
    return path


def write_text(path: str | Path, text: str, *, force: bool = False) -> Path:
    """Write a text file atomically (refusing to overwrite without ``force``)."""
    path = check_writable(path, force)
    write_atomic(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))
    return path


def write_json(path: str | Path, data: Any, *, force: bool = False) -> Path:
    """Write JSON atomically; NaN/inf are refused (they are not JSON)."""
    return write_text(path, json.dumps(data, indent=2, allow_nan=False) + "\n", force=force)


def read_json(path: str | Path, what: str = "JSON file") -> Any:
    """Read a JSON file, with one-line errors."""
    path = Path(path)
    if not path.is_file():
        raise StraussFitError(f"{what} not found: {path}")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise StraussFitError(f"cannot read {what} {path}: {exc}") from None

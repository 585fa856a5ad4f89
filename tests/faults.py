"""Fault injection for the tests: a folder on a disk that fills up.

:class:`Disk` is a folder with a chosen number of bytes free, in one of two ways:

- ``tmpfs``: a real, small tmpfs mounted there (needs root and a kernel that allows it;
  the fixture skips this variant where ``mount`` fails), filled with a ballast file; every
  writer meets a real ``ENOSPC`` from the kernel, at ``write``, ``close`` or ``fsync``;
- ``patched``: the functions through which every output's bytes reach the disk
  (:func:`strauss_fit.io.files._write_file`, and ``_append_file`` for progress files) are
  patched to write what still fits and then raise ``ENOSPC``, the space used being the size
  of the files in the folder.

:meth:`Disk.free_up` then makes room again (removes the ballast, lifts the budget).
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

import strauss_fit.io.files

TMPFS_SIZE = 16 * 1024 * 1024
BALLAST = ".ballast"


def used_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file() and p.name != BALLAST)


class Disk:
    def __init__(self, folder: Path, mode: str, monkeypatch: pytest.MonkeyPatch):
        self.folder, self.mode, self.monkeypatch = folder, mode, monkeypatch
        self.capacity: int | None = None
        folder.mkdir()
        if mode == "tmpfs":
            if shutil.which("mount") is None:
                pytest.skip("no mount command")
            done = subprocess.run(
                ["mount", "-t", "tmpfs", "-o", f"size={TMPFS_SIZE}", "tmpfs", str(folder)],
                capture_output=True,
                text=True,
            )
            if done.returncode != 0:
                pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
        else:
            real = strauss_fit.io.files._write_file

            def write(path: Path, data) -> None:
                path = Path(path)
                if self.capacity is None or folder not in path.parents:
                    return real(path, data)
                room = self.capacity - used_bytes(folder)
                if len(data) <= room:
                    return real(path, data)
                real(path, bytes(data[: max(room, 0)]))
                raise strauss_fit.io.files.no_space(path)

            real_append = strauss_fit.io.files._append_file

            def append(path: Path, data) -> None:
                path = Path(path)
                if self.capacity is None or folder not in path.parents:
                    return real_append(path, data)
                if len(data) > self.capacity - used_bytes(folder):
                    raise strauss_fit.io.files.no_space(path)  # the real one rolls a partial append back
                return real_append(path, data)

            monkeypatch.setattr(strauss_fit.io.files, "_write_file", write)
            monkeypatch.setattr(strauss_fit.io.files, "_append_file", append)

    def fill(self, free: int) -> None:
        """Leave ``free`` bytes free (about: a tmpfs counts whole pages)."""
        if self.mode == "tmpfs":
            ballast = self.folder / BALLAST
            ballast.unlink(missing_ok=True)
            available = os.statvfs(self.folder).f_bavail * os.statvfs(self.folder).f_frsize
            with open(ballast, "wb") as handle:
                handle.write(b"\0" * max(available - free, 0))
        else:
            self.capacity = used_bytes(self.folder) + free

    def free_up(self) -> None:
        if self.mode == "tmpfs":
            (self.folder / BALLAST).unlink(missing_ok=True)
        else:
            self.capacity = None

    def files(self) -> list[str]:
        """Everything in the folder but the ballast, temporary files included."""
        return sorted(str(p.relative_to(self.folder)) for p in self.folder.rglob("*") if p.name != BALLAST)

    def close(self) -> None:
        if self.mode == "tmpfs":
            subprocess.run(["umount", "-l", str(self.folder)], capture_output=True)


@pytest.fixture(name="disk", params=["tmpfs", "patched"])
def disk_fixture(request, tmp_path, monkeypatch):
    """A :class:`Disk` in ``tmp_path/disk``, both ways."""
    d = Disk(tmp_path / "disk", request.param, monkeypatch)
    yield d
    d.close()

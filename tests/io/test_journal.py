"""The conversions' progress file: appends are all or nothing on a full disk, a killed
append's partial line is dropped, a file of other work is refused."""

import pytest
from faults import disk_fixture  # noqa: F401 - the fixture "disk"

from strauss_fit.io.files import WriteError
from strauss_fit.io.journal import Journal, JournalError


def test_a_full_disk_leaves_the_progress_file_as_it_was(disk):
    path = disk.folder / "out.json.partial"
    journal = Journal(path, "key")
    journal.append([{"index": 0, "result": "x" * 100}])
    before = path.read_bytes()
    disk.fill(2048)
    with pytest.raises(WriteError, match=f"cannot write {path}: No space left on device"):
        journal.append([{"index": 1, "result": "y" * 200_000}])
    assert path.read_bytes() == before  # rolled back: no partial line
    disk.free_up()
    journal.append([{"index": 1, "result": "z"}])
    assert [r["index"] for r in Journal(path, "key").open()] == [0, 1]


def test_a_killed_append_is_dropped_and_other_work_refused(tmp_path):
    path = tmp_path / "p.partial"
    Journal(path, "key").append([{"index": 0}, {"index": 1}])
    with open(path, "ab") as handle:
        handle.write(b'{"index": 2, "res')
    assert [r["index"] for r in Journal(path, "key").open()] == [0, 1]
    assert path.read_bytes().endswith(b'{"index":1}\n')  # truncated back to the last whole line
    with pytest.raises(JournalError, match="progress of another run"):
        Journal(path, "other").open()
    path.write_text("not a progress file\n")
    with pytest.raises(JournalError, match="not a strauss-fit progress file"):
        Journal(path, "key").open()

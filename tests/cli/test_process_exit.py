"""How the ``strauss-fit`` process ends (`strauss_fit_cli.interrupts.leave_process`): it
skips the interpreter's teardown, but keeps everything a normal exit gives — the status,
the whole of the buffered output, the exit handlers."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

# The process as the console script runs it (console_main), with an exit handler of its
# own that must still run, and its output buffered (a pipe, not a terminal).
SCRIPT = """
import atexit, sys
atexit.register(lambda: print("exit handler ran"))
sys.argv = ["strauss-fit", *sys.argv[1:]]
from strauss_fit_cli.main import console_main
console_main()
print("main() returned")  # it must not: the process ends inside it
"""


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", SCRIPT, *args], capture_output=True, text=True, timeout=300)


def test_success_keeps_output_and_exit_handlers():
    done = run("--version")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("strauss-fit ") and lines[-1] == "exit handler ran"
    assert "main() returned" not in done.stdout


@pytest.mark.parametrize("args", [("fit", "no-such-target.exr"), ("no-such-command",)])
def test_error_status_and_message_survive(args, tmp_path):
    done = run(*args)
    assert done.returncode == 2
    assert done.stderr.startswith("strauss-fit: error: ") and len(done.stderr.strip().splitlines()) == 1
    assert done.stdout.splitlines() == ["exit handler ran"]


def test_a_long_buffered_output_arrives_whole():
    # --help of every command: many kilobytes written through a pipe's buffer, flushed
    # before the process leaves
    in_process = "import sys; from strauss_fit_cli.main import main; sys.exit(main(['render', '--help']))"
    expected = subprocess.run(
        [sys.executable, "-c", in_process],
        capture_output=True,
        text=True,
        timeout=300,
    ).stdout
    done = run("render", "--help")
    assert done.returncode == 0
    assert len(expected) > 1000 and done.stdout == expected + "exit handler ran\n"


def test_main_without_arguments_returns_to_its_caller():
    # a script or notebook calling main() itself keeps its interpreter
    script = (
        "import sys; sys.argv = ['strauss-fit', '--version']\n"
        "from strauss_fit_cli.main import main\n"
        "code = main()\n"
        "print('returned', code)\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and done.stdout.splitlines()[-1] == "returned 0"


# the standard output replaced by one whose last flush fails as the given error
FAILING_FLUSH = """
import errno, io, sys
from strauss_fit_cli.interrupts import leave_process

class Failing(io.StringIO):
    def flush(self):
        raise {error}

sys.stdout = Failing()
print("a result table")
leave_process(0)
"""


@pytest.mark.parametrize(
    "error, message",
    [
        (
            "OSError(errno.ENOSPC, 'No space left on device')",
            "cannot write the standard output: No space left on device",
        ),
        ("BrokenPipeError(errno.EPIPE, 'Broken pipe')", None),  # `| head`: quiet, as Python's own exit
    ],
)
def test_output_that_cannot_be_flushed_is_status_120(error, message):
    script = FAILING_FLUSH.format(error=error)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert done.returncode == 120
    assert done.stderr == ("" if message is None else f"strauss-fit: error: {message}\n")


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full (a device that is always full)")
@pytest.mark.parametrize("args", [("--version",), ("--help",), ("render", "--help")])
def test_help_or_version_into_a_full_disk_is_an_error(args):
    # argparse's own printing swallows the write's error: this exited 0 with nothing written
    script = (
        "import sys; sys.argv = ['strauss-fit', *sys.argv[1:]]\n"
        "from strauss_fit_cli.main import console_main\n"
        "console_main()\n"
    )
    with open("/dev/full", "w") as full:
        done = subprocess.run(
            [sys.executable, "-c", script, *args], stdout=full, stderr=subprocess.PIPE, text=True, timeout=300
        )
    assert done.returncode == 2
    assert done.stderr == "strauss-fit: error: cannot write the standard output: No space left on device\n"

"""Ctrl-C at any moment, for real: the ``strauss-fit`` process gets SIGINT while Python
starts and imports, while JAX compiles, while the fit runs, between the written files,
and inside a callback that swallows exceptions (as JAX's garbage-collection hook does).
Every time: exit status 130, one line "strauss-fit: interrupted", no traceback, no
output file and no temporary file left.

The processes run side by side (each waits for its own moment), so the whole module
costs about one fit.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

import strauss_fit as sf
from strauss_fit.io.images import write_image
from support import SMALL_MATERIAL, key_and_fill_scene, key_and_fill_toml, noisy_target

COMMAND = Path(sys.executable).parent / "strauss-fit"

#: Runs ``main`` in a fresh process, after arranging for SIGINT to arrive at a chosen point
#: (from inside the process, so the moment is exact; the signal itself is real).
HARNESS = """
import gc, os, signal, sys
import strauss_fit.io.files as files
from strauss_fit_cli.main import main
where = sys.argv[1]
def press():
    os.kill(os.getpid(), signal.SIGINT)
if where == "between-files":
    real = files._write_file
    calls = []
    def write(path, data):
        real(path, data)
        calls.append(path)
        if len(calls) == 1:
            press()  # the first file is written in full; the others are not yet
    files._write_file = write
elif where == "swallowed":
    import strauss_fit
    real_fit = strauss_fit.fit
    def fit(*args, **kwargs):
        def callback(phase, info):
            # raised inside a gc callback: Python prints "Exception ignored" and goes on,
            # as with JAX's _xla_gc_callback
            gc.callbacks.remove(callback)
            press()
        gc.callbacks.append(callback)
        gc.collect()
        return real_fit(*args, **kwargs)
    strauss_fit.fit = fit  # what the fit command calls
sys.exit(main(sys.argv[2:]))
"""


@pytest.fixture(autouse=True)
def interruptible_children():
    """The processes start with Ctrl-C honoured, as from a terminal, even when the tests
    themselves run with SIGINT ignored (a background job of a non-interactive shell, such
    as ``nohup bash .ci/run &``): an ignored SIGINT is inherited, and the command rightly
    leaves it ignored (:func:`strauss_fit_cli.interrupts.install`), which would make every
    moment here look like a lost Ctrl-C."""
    previous = signal.getsignal(signal.SIGINT)
    if previous is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)  # a caught signal is reset to the default by exec
    yield
    if previous is signal.SIG_IGN:
        signal.signal(signal.SIGINT, previous)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("interrupt-inputs")
    (folder / "scene.toml").write_text(key_and_fill_toml(24, material=SMALL_MATERIAL))
    scene = key_and_fill_scene(24, material=SMALL_MATERIAL)
    material = sf.Material(color=(0.7, 0.4, 0.2), smoothness=0.6, metalness=0.4)
    write_image(folder / "target.exr", noisy_target(scene, material, 0.01, seed=3).pixels)
    return folder


def fit_argv(inputs: Path, out: Path) -> list[str]:
    return [
        "fit",
        str(inputs / "target.exr"),
        "--scene",
        str(inputs / "scene.toml"),
        "--free",
        "color,smoothness,metalness",
        "--quality",
        "fast",
        "-o",
        str(out / "result.json"),
        "--render-fit",
        str(out / "fitted.exr"),
    ]


class Run:
    """A process, the moment at which it gets SIGINT (seconds after its start, or when a
    line on its stderr starts with a prefix), and what came of it."""

    def __init__(self, argv: list[str], out: Path, *, loaded: str | None = None, on_line: str | None = None):
        self.out = out
        out.mkdir()
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        self.loaded, self.on_line = loaded, on_line
        self.err_lines: list[str] = []
        self.out_text: list[str] = []
        self.sent = threading.Event()
        self.readers = [
            threading.Thread(target=self._read, daemon=True),
            threading.Thread(target=lambda: self.out_text.append(self.process.stdout.read()), daemon=True),
        ]
        for reader in self.readers:
            reader.start()
        if loaded is not None:
            threading.Thread(target=self._watch_imports, daemon=True).start()

    def _watch_imports(self) -> None:
        """SIGINT as soon as the process has loaded the shared library ``loaded`` (its
        memory map names it): a moment inside the imports however loaded the machine is."""
        maps = Path(f"/proc/{self.process.pid}/maps")
        while self.process.poll() is None and not self.sent.is_set():
            try:
                if self.loaded in maps.read_text():
                    self._press()
                    return
            except OSError:
                return
            time.sleep(0.002)

    def _press(self) -> None:
        if not self.sent.is_set() and self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        self.sent.set()

    def _read(self) -> None:
        for line in self.process.stderr:
            self.err_lines.append(line)
            if self.on_line is not None and line.startswith(self.on_line):
                self._press()

    def finish(self, timeout: float = 240.0) -> tuple[int, str, str]:
        self.process.wait(timeout=timeout)
        for reader in self.readers:
            reader.join(timeout=10)
        return self.process.returncode, "".join(self.out_text), "".join(self.err_lines)


LATE = """
import os, signal, sys
import strauss_fit.io.files as files
from strauss_fit_cli.main import main
real = files.Outputs.commit
def commit(self, *, final=False):
    done = real(self, final=final)
    os.kill(os.getpid(), signal.SIGINT)  # a moment too late
    return done
files.Outputs.commit = commit
sys.exit(main(sys.argv[1:]))
"""


def test_ctrl_c_at_any_moment_exits_130_and_writes_nothing(inputs, tmp_path):
    if not Path("/proc/self/maps").exists():
        pytest.skip("needs /proc to see what a process has loaded")
    if not COMMAND.exists():
        pytest.skip(f"the strauss-fit command is not installed beside {sys.executable}")
    runs = {}
    # while the library imports JAX and NumPy and loads JAX's compiled core (Python's own start-up, until
    # its site module is imported, is not ours: a SIGINT there ends the process before any
    # strauss-fit code runs, with nothing written)
    for library in ("cpu_feature_guard", "_multiarray_umath", "jaxlib/_jax"):
        out = tmp_path / f"importing-{library.replace('/', '-')}"
        runs[f"while importing {library}"] = Run([str(COMMAND), *fit_argv(inputs, out)], out, loaded=library)
    for moment, prefix in (
        ("while JAX compiles the first guess", "... computing the first guess"),
        ("while the fit runs", "... fitting"),
    ):
        out = tmp_path / moment.replace(" ", "-")
        runs[moment] = Run([str(COMMAND), *fit_argv(inputs, out)], out, on_line=prefix)
    for moment in ("between-files", "swallowed"):
        out = tmp_path / moment
        argv = [sys.executable, "-c", HARNESS, moment, *fit_argv(inputs, out)]
        runs[moment] = Run(argv, out)
    # and a moment too late: once the outputs are committed, Ctrl-C changes nothing
    late = Run([sys.executable, "-c", LATE, *fit_argv(inputs, tmp_path / "late")], tmp_path / "late")
    code, stdout, stderr = late.finish()
    assert code in (0, 1) and "interrupted" not in stderr and "wrote" in stdout, stderr
    assert sorted(p.name for p in late.out.iterdir()) == ["fitted.compare.png", "fitted.exr", "result.json"]
    for moment, run in runs.items():
        code, stdout, stderr = run.finish()
        assert run.sent.is_set() or moment in ("between-files", "swallowed"), f"{moment}: the signal was never sent"
        assert code == 130, f"{moment}: exit status {code}\n{stderr}"
        assert stderr.rstrip().endswith("strauss-fit: interrupted"), f"{moment}: {stderr}"
        assert "Traceback" not in stderr and "Exception ignored" not in stderr, f"{moment}: {stderr}"
        assert "wrote" not in stdout, moment
        assert sorted(p.name for p in run.out.iterdir()) == [], f"{moment}: left {list(run.out.iterdir())}"


LATE = """
import os, signal, sys
import strauss_fit.io.files as files
from strauss_fit_cli.main import main
real = files.Outputs.commit
def commit(self, *, final=False):
    done = real(self, final=final)
    os.kill(os.getpid(), signal.SIGINT)  # a moment too late
    return done
files.Outputs.commit = commit
sys.exit(main(sys.argv[1:]))
"""


#: A target that blocks: Python's own open of a FIFO waits for a writer (the check that
#: refuses FIFOs, and the non-blocking open behind it, are taken away to reach the wait).
BLOCKING_OPEN = """
import os, sys
import strauss_fit.io.images as images
images.check_input_file = lambda path, what, error: __import__("pathlib").Path(path)
os.O_NONBLOCK = 0
from strauss_fit_cli.main import main
sys.argv = ["strauss-fit", *sys.argv[1:]]
sys.exit(main())
"""

#: Compiled code that does not return for a long time with Python's lock released (a
#: jitted loop), while an output is staged: only the watchdog can end it.
STUCK_IN_COMPILED_CODE = """
import sys
import strauss_fit.io.files as files
import strauss_fit_cli.render_cmd as render_cmd
from strauss_fit_cli.main import main
def stuck(args):
    import jax, jax.numpy as jnp
    spin = jax.jit(lambda n: jax.lax.fori_loop(0, n, lambda i, x: jnp.sin(x) + 1e-9, 0.0))
    spin(10).block_until_ready()
    with files.Outputs() as out:
        out.add_text(args.output, "staged")
        print("... spinning", file=sys.stderr, flush=True)
        spin(2**31 - 1).block_until_ready()
        out.commit()
    return 0
render_cmd.run = stuck
sys.argv = ["strauss-fit", "render", "scene.toml", "-o", sys.argv[1]]
sys.exit(main())
"""


def test_ctrl_c_inside_a_blocking_open_or_compiled_code_exits_130(inputs, tmp_path):
    # before: a FIFO target hung in open() for good, and two Ctrl-C did not stop it; a
    # SIGINT during a long compiled computation waited for its end
    fifo = tmp_path / "fifo.exr"
    os.mkfifo(fifo)
    out = tmp_path / "open"
    argv = [sys.executable, "-c", BLOCKING_OPEN, *fit_argv(inputs, out)]
    argv[argv.index(str(inputs / "target.exr"))] = str(fifo)
    blocked = Run(argv, out, on_line="strauss-fit: never")
    spin = [sys.executable, "-c", STUCK_IN_COMPILED_CODE, str(tmp_path / "spin" / "x.txt")]
    spinning = Run(spin, tmp_path / "spin", on_line="... spinning")
    time.sleep(10)  # long enough to be inside the blocking open
    blocked._press()
    for moment, run in (("a blocking open", blocked), ("compiled code", spinning)):
        code, stdout, stderr = run.finish(timeout=120)
        assert run.sent.is_set(), f"{moment}: the signal was never sent"
        assert code == 130, f"{moment}: exit status {code}\n{stderr}"
        assert stderr.rstrip().endswith("strauss-fit: interrupted") and "Traceback" not in stderr, stderr
        assert sorted(p.name for p in run.out.iterdir()) == [], f"{moment}: left {list(run.out.iterdir())}"

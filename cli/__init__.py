"""The ``strauss-fit`` command line (installed as the package ``strauss_fit_cli``).

When this package is imported by the ``strauss-fit`` command itself, the interrupt handler
of `strauss_fit_cli.interrupts` is installed first, before anything heavy is imported,
so that Ctrl-C is honoured from the first instant (exit status 130, nothing written), and
its watchdog started, which honours it even inside blocking compiled code.
"""

import sys as _sys
from pathlib import Path as _Path

from . import interrupts as _interrupts

if _sys.argv and (_Path(_sys.argv[0]).stem == "strauss-fit" or _sys.argv[0] == "-m"):
    _interrupts.install()
    _interrupts.watch()

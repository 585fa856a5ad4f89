"""A command's start-up (issue 27, cold start): what ``strauss-fit fit`` imports before it
fits. SciPy (1.5-1.8 s of a command's imports on two cores under load 11) is imported
only where a noise estimate needs it, never by the command line's modules themselves."""

from __future__ import annotations

import subprocess
import sys


def test_the_fit_command_imports_no_scipy_before_it_needs_it():
    code = (
        "import sys\n"
        "import strauss_fit, strauss_fit_cli.main, strauss_fit_cli.fit_cmd, strauss_fit.fitting.folder\n"
        "from strauss_fit.stats import noise\n"
        "print(sorted(m for m in sys.modules if m == 'scipy' or m.startswith('scipy.')))\n"
    )
    finished = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert finished.stdout.strip() == "[]"


def test_the_noise_estimate_still_finds_scipy_when_it_runs():
    """The imports moved into the functions that use them: an estimate still works (and
    loads SciPy then)."""
    code = (
        "import sys\n"
        "import numpy as np\n"
        "from strauss_fit.stats.noise import estimate_noise\n"
        "rng = np.random.default_rng(0)\n"
        "image = 0.5 + 0.01 * rng.normal(size=(64, 64, 3))\n"
        "estimate = estimate_noise(image, np.ones((64, 64), bool))\n"
        "print(round(float(np.mean(estimate.sigma)), 3), 'scipy.ndimage' in sys.modules)\n"
    )
    finished = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert finished.stdout.split() == ["0.01", "True"]

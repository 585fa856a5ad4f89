"""What both conversion directions share: the Phong rendering kernel, the residual
statistics of a result, the residual scale of a target, error results and notes.

Both `strauss_fit.convert._to_strauss` and `strauss_fit.convert._to_phong`
(and the batch driver, `strauss_fit.convert._batches`) build their results with
these, so that a result reads the same whichever direction made it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..color import delta_e_2000
from ..engine import Kernel
from ..errors import StraussFitError
from ..fitting.identifiability import reference_noise_level
from ..io.material_tables import Entry
from ..models.phong import PhongMaterial
from ..rendering.phong import render_phong
from ..scene.loading import Scene


def _phong_pixels(scene: Scene, material: PhongMaterial, index: Any) -> Any:
    image, _ = render_phong(scene, material)
    return image.reshape(-1, 3)[index]


#: The Phong rendering (N, 3) of a material in a scene at the flat pixel ``index``; a
#: `Kernel`, so that a chunk's targets render as one call.
phong_pixels = Kernel(_phong_pixels, "phong_pixels")


def residual_stats(model: np.ndarray, target: np.ndarray) -> dict[str, float]:
    """RMS and largest absolute difference in linear RGB, mean and 95th percentile of the
    per-pixel CIEDE2000 (`strauss_fit.color.delta_e_2000`: exposed for ``target``)."""
    diff = model - target
    delta = delta_e_2000(model, target)
    return {
        "rms": float(np.sqrt(np.mean(diff**2))),
        "max_abs": float(np.max(np.abs(diff))),
        "delta_e2000_mean": float(np.mean(delta)),
        "delta_e2000_p95": float(np.percentile(delta, 95)),
    }


def scale_of(pixels: np.ndarray) -> float:
    """Residual scale as in a fit (`strauss_fit.fitting.problem`): reference noise × √(values)."""
    return reference_noise_level(pixels) * math.sqrt(pixels.size)


def error_result(entry: Entry, message: str) -> dict[str, Any]:
    """The result of a material that could not be converted: its name, source, the
    ``message`` and the entry's notes."""
    return {
        "name": entry.name,
        "source": entry.source,
        "status": "error",
        "message": message,
        "notes": list(entry.notes),
    }


def message_of(exc: BaseException) -> str:
    """The one-line message of an error result: a `StraussFitError`'s
    own text, else the exception's type and first line (a bug, not a bad material)."""
    if isinstance(exc, StraussFitError):
        return str(exc)
    text = str(exc).strip().splitlines()
    return f"unexpected {type(exc).__name__}: {text[0] if text else 'no message'}"


def lobe_note(width: int, exponent: float) -> str | None:
    """A note when a highlight of ``exponent`` is narrower than a pixel of the
    ``width``-pixel conversion image resolves, else None."""
    if exponent <= 0:
        return None
    half_width = math.acos(0.5 ** (1.0 / exponent))  # where cos^n beta = 1/2
    pitch = 2.0 * 2.0 / width  # beta moves twice as fast as the normal
    if half_width < pitch:
        return (
            f"the highlight (n = {exponent:.4g}) is narrower than a pixel of the {width}-pixel "
            "conversion image; its shape is poorly constrained (use a larger --size)"
        )
    return None


def not_run() -> dict[str, Any]:
    """The solver record of a material that was not fitted (it renders black); a fresh
    dict for every result."""
    return {"status": "not run", "steps": 0, "best_start": None, "starts": 0, "at_bound": []}


def require_finite(values: Any, message: str) -> None:
    """Raise `StraussFitError` with ``message`` unless every
    value is finite (a material's conversion then ends as an error result)."""
    if not np.all(np.isfinite(values)):
        raise StraussFitError(message)

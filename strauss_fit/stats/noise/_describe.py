"""Where a target's noise model comes from (`describe_noise`): the level given, else
the target's sidecar (a sensor or a renderer's measured noise), else an estimate from the
image itself, remembered per image content.
"""

from __future__ import annotations

import copy
import hashlib
import math
import threading
from collections import OrderedDict
from pathlib import Path

import numpy as np

from ..._escaping import escape
from ._additive import estimate_noise
from ._errors import NoiseEstimationError
from ._level_line import estimate_noise_model
from ._model import NoiseModel, _triple, _zero_or_in_range, check_noise_level
from ._quantisation import quantisation_sigma

#: Relative rounding of stored floating-point values (EXR, TIFF, PFM), by pixel type: the
#: floor of a noise-free render's noise.
STORAGE_PRECISION = {"half": 2.0**-11, "float": 2.0**-24, "double": 2.0**-53}
#: Fewest residual positions for a signal-dependent (Poisson–Gaussian) model from the image:
#: on smaller images (a 24 × 24 sphere has ~300) its slope test fires on chance structure.
MIN_PIXELS_SIGNAL_DEPENDENT = 2000


def storage_precision(path: str | None) -> float:
    """The relative rounding of a floating-point image file's values (0 for 8-bit and
    unknown files: their floor is the quantisation)."""
    if not path or not Path(path).is_file():
        return 0.0
    try:
        import OpenImageIO as oiio

        image = oiio.ImageInput.open(str(path))
        if image is None:
            oiio.geterror()  # read (and drop) the error, or OpenImageIO prints it at exit
            return 0.0
        try:
            basetype = image.spec().format.basetype
        finally:
            image.close()
    except Exception:  # a header we cannot read only loses the floor
        return 0.0
    names = {oiio.HALF: "half", oiio.FLOAT: "float", oiio.DOUBLE: "double"}
    return STORAGE_PRECISION.get(names.get(basetype, ""), 0.0)


def sidecar_path(path: str | Path) -> Path:
    """Where an image's sidecar would be: ``ID.json`` beside ``ID.png`` (docs/datasets.md)."""
    return Path(path).with_suffix(".json")


def read_sidecar(path: str | None) -> dict | None:
    """The synth sidecar beside an image (``ID.png`` → ``ID.json``, see docs/datasets.md)
    if there is one and it is a strauss-fit sample description, else None."""
    return _sample_description(_sidecar_json(path)[0])


def unusable_sidecar(path: str | None, sidecar: dict | None) -> str | None:
    """Why a sidecar beside the image at ``path`` gives no noise although it is there, or
    None: a file that is not readable JSON, or a strauss-fit sample description whose
    ``noise`` or ``sensor`` entry is not a valid noise level. Other JSON files are not
    sidecars (a file of the user's own that shares the image's name) and give None.
    ``sidecar``: what `read_sidecar` made of it."""
    return _sidecar_problem(path, sidecar, _sidecar_json(path)[1] if sidecar is None else None)


def _sidecar_json(path: str | None) -> tuple[object, str | None]:
    """The JSON value in the file beside the image at ``path`` (None where there is no such
    file or it cannot be read) and why it could not be read (None where it was, or where
    there is none)."""
    if not path:
        return None, None
    import json

    candidate = sidecar_path(path)
    if not candidate.is_file():  # a regular file only: reading a FIFO would block
        return None, None
    try:
        return json.loads(candidate.read_text(encoding="utf-8")), None
    except (OSError, ValueError, RecursionError) as exc:  # RecursionError: nested too deeply
        return None, exc.strerror if isinstance(exc, OSError) and exc.strerror else "not readable JSON"


def _sample_description(data: object) -> dict | None:
    """``data`` if it is a strauss-fit sample description, else None."""
    return data if isinstance(data, dict) and data.get("format") == "strauss-fit synth sample" else None


def _sidecar_problem(path: str | None, sidecar: dict | None, unread: str | None) -> str | None:
    """`unusable_sidecar`'s note, from the sidecar read and why the file was not
    (``unread``, from `_sidecar_json`)."""
    if not path:
        return None
    name = escape(sidecar_path(path).name, newlines=True)  # quoted in one line of the fit's output
    if unread is not None:
        return f"the sidecar {name} beside the target was not read ({unread}); the noise is not from it"
    if sidecar and _from_sidecar(sidecar) is None and ("noise" in sidecar or "sensor" in sidecar):
        return (
            f"the sidecar {name} holds no valid noise level (its 'noise' or 'sensor' entry is damaged "
            "or out of range); the noise is not from it"
        )
    return None


def _from_sidecar(sidecar: dict) -> tuple[np.ndarray, np.ndarray, str] | None:
    """(a, b, note) of a sidecar's noise: a renderer's measured per-channel noise
    (``noise.per_channel``) or the synthetic sensor (Var = E/gain + read_noise²)."""
    noise = sidecar.get("noise")
    measured = noise.get("per_channel") if isinstance(noise, dict) else None
    if measured is not None:
        try:
            sigma = _triple(measured)
        except (TypeError, ValueError):
            sigma = np.full(3, np.nan)
        if all(_zero_or_in_range(v) for v in sigma):
            return np.zeros(3), sigma**2, "measured noise recorded in the sidecar"
    sensor = sidecar.get("sensor")
    if isinstance(sensor, dict):
        try:
            gain, read = float(sensor.get("gain", 0.0)), float(sensor.get("read_noise", 0.0))
        except (TypeError, ValueError):
            return None
        # the shot noise's σ at level 1 is 1/√gain: in range too
        shot_ok = gain == 0 or (math.isfinite(gain) and gain > 0 and _zero_or_in_range(1.0 / math.sqrt(gain)))
        if not (shot_ok and _zero_or_in_range(read)):
            return None
        a = np.full(3, 1.0 / gain if gain > 0 else 0.0)
        note = f"sensor of the sidecar (gain {gain:g}, read noise {read:g})"
        if gain == 0 and read == 0:
            note = "the sidecar's sensor adds no noise: only the file's precision limits the fit"
        return a, np.full(3, read**2), note
    return None


def describe_noise(
    pixels: np.ndarray,
    usable: np.ndarray,
    *,
    encoding: str = "linear",
    path: str | None = None,
    given: float | tuple | None = None,
    sidecar: dict | None = None,
) -> NoiseModel:
    """The noise model of a target image (see `NoiseModel`): the ``given`` level if
    any, else the ``sidecar``'s (read beside ``path`` when not passed; pass ``{}`` to
    ignore it), else estimated from the image over the ``usable`` pixels (the sphere's
    fully covered ones), signal-dependent when the estimate finds shot noise. An 8-bit sRGB
    target (``encoding="srgb"``) adds its quantisation; a float file its precision. An
    estimate is computed once per image content and reused (a copy) when the same image is
    described again."""
    pixels = np.asarray(pixels, dtype=np.float64)
    quantised = encoding == "srgb"
    storage = 0.0 if quantised else storage_precision(path)
    if given is not None:
        sigma = check_noise_level(given)
        return NoiseModel("given", np.zeros(3), sigma**2, quantised, storage, notes=["the noise level given"])
    unread = None
    if sidecar is None:  # read once: the sidecar, or why the file beside the image was not read
        data, unread = _sidecar_json(path)
        sidecar = _sample_description(data)
    described = _from_sidecar(sidecar) if sidecar else None
    if described is not None:
        a, b, note = described
        return NoiseModel("sensor", a, b, quantised, storage, notes=[note])
    problem = _sidecar_problem(path, sidecar, unread)
    model = _described_from_image(pixels, usable, quantised, storage)
    if problem is not None:
        model.sidecar_problem = problem
        model.notes.insert(0, problem)
    return model


def _described_from_image(pixels: np.ndarray, usable: np.ndarray, quantised: bool, storage: float) -> NoiseModel:
    """The noise model estimated from the image, once per image content (a copy)."""
    usable = np.asarray(usable, dtype=bool)
    key = _image_key(pixels, usable, quantised, storage)
    with _ESTIMATED_LOCK:
        known = _ESTIMATED.get(key)
        if known is not None:
            _ESTIMATED.move_to_end(key)
            return copy.deepcopy(known)
    described = _estimated_noise(pixels, usable, quantised, storage)
    with _ESTIMATED_LOCK:
        _ESTIMATED[key] = copy.deepcopy(described)
        while len(_ESTIMATED) > ESTIMATED_KEPT:
            _ESTIMATED.popitem(last=False)
    return described


#: Noise models estimated from images, by the image's content (`_image_key`): a
#: target fitted again (another loss, other free parameters, a batch's retry, a benchmark)
#: is the same image with the same noise, and estimating it costs a third of a warm fit.
_ESTIMATED: OrderedDict[bytes, NoiseModel] = OrderedDict()
_ESTIMATED_LOCK = threading.Lock()  # fits may describe targets from several threads
#: How many estimates `_ESTIMATED` keeps (the least recently used go first).
ESTIMATED_KEPT = 32


def _image_key(pixels: np.ndarray, usable: np.ndarray, quantised: bool, storage: float) -> bytes:
    """What decides an image's estimated noise: its values, the pixels used, the 8-bit
    quantisation and the file's precision. SHA-1 as a content key, not for security: a 256²
    image hashes in 0.8 ms where BLAKE2b took 1.8 (2026-12-04)."""
    digest = hashlib.sha1(usedforsecurity=False)
    for array in (pixels, usable):
        digest.update(repr((array.shape, array.dtype.str)).encode())
        digest.update(np.ascontiguousarray(array).data)
    digest.update(repr((quantised, storage)).encode())
    return digest.digest()


def _estimated_noise(pixels: np.ndarray, usable: np.ndarray, quantised: bool, storage: float) -> NoiseModel:
    """The noise model estimated from the image itself (`describe_noise`'s last case)."""
    try:
        estimate = estimate_noise(pixels, usable, censor=(0.0, 1.0) if quantised else None)
    except NoiseEstimationError as exc:
        return NoiseModel("unknown", np.zeros(3), np.zeros(3), quantised, storage, notes=[str(exc)])
    if not np.all(estimate.resolved):
        why = (
            "the image's fine detail, not noise, sets its high-frequency content (a noise-free render, or a "
            "pattern seen in the sphere)"
        )
        return NoiseModel(
            "unknown", np.zeros(3), np.zeros(3), quantised, storage, notes=[why], details=estimate.to_dict()
        )
    variance = estimate.sigma**2
    if quantised:  # the estimate holds the quantisation pooled over the pixels it used; each pixel gets its own
        variance = np.maximum(variance - np.mean(quantisation_sigma(pixels[usable]) ** 2, axis=0), 0.0)
    a = np.zeros(3)
    note = "estimated from the image (additive, per channel)"
    if estimate.n_pixels >= MIN_PIXELS_SIGNAL_DEPENDENT:
        try:
            model = estimate_noise_model(
                pixels, usable, quantisation="srgb8" if quantised else None, censor=(0.0, 1.0) if quantised else None
            )
        except NoiseEstimationError:
            model = None
        if model is not None and np.any(model.signal_dependent) and np.all(model.channels_independent):
            # the line must agree with the additive estimate on average over the pixels it
            # describes, within the latter's own uncertainty (3 standard errors of σ²)
            level = pixels[usable]
            mean_variance = np.mean(model.a * np.maximum(level, 0.0) + model.b, axis=0)
            tolerance = 3 * 2 * np.asarray(estimate.relative_stderr, dtype=float) * variance
            if np.all(np.abs(mean_variance - variance) <= tolerance):
                a, variance = model.a.copy(), model.b.copy()
                note = "estimated from the image (signal-dependent: Var = a·L + b per channel)"
    return NoiseModel(
        "image",
        a,
        variance,
        quantised,
        storage,
        relative_stderr=np.asarray(estimate.relative_stderr, dtype=float),
        notes=[note],
        details=estimate.to_dict(),
    )

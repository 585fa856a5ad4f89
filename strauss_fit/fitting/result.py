"""What a fit found (`FitResult`), and its JSON form.

`FitResult.to_json` writes the result as ``strauss-fit fit`` saves it (the contract
of docs/formats.md, "Fit result (JSON)": the material's values at the top level, then ``free``, ``held``,
``uncertainty``, ``correlation``, ``residual``, ``solver``, ...); `FitResult.from_json`
is the one reader of that format, used wherever a fit result is read back (the sampler,
the posterior, the Laplace summary, the report).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import StraussFitError
from ..models.material import PARAMETER_NAMES, Material

if TYPE_CHECKING:
    from .problem import Problem

#: Top-level keys of a fit result's JSON that are FitResult fields (besides the material's).
_FIELDS = {
    "free": "free",
    "held": "held",
    "uncertainty": "uncertainty",
    "correlation": "correlation",
    "residual": "residual",
    "solver": "solver",
    "starts": "starts",
    "start_spread": "start_spread",
    "lights": "lights",
    "pixels_used": "pixels_used",
    "wall_time_s": "wall_time_s",
    "timing": "compile_and_solve",
    "notes": "notes",
    "settings": "settings",
    "warnings": "warnings",
    "exposure": "exposure",
    "uncertainty_method": "uncertainty_method",
    "uncertainty_laplace": "uncertainty_laplace",
    "equivalence": "equivalence",
}


class FitResultError(StraussFitError):
    """A JSON document is not a strauss-fit fit result."""


def _finite(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _check_recorded(data: dict, free: list[str], lights: dict[str, float], fields: dict[str, Any]) -> None:
    """What the readers of a fit result rely on (the report, ``sample --fit``): every freed
    name has a value, every ± is a finite number (three for the colour), the correlation
    matrix is square with a label per row, the exposure a positive finite number.
    Raises `FitResultError` naming the first that is not."""
    bad = "the fit result is not a strauss-fit fit result"
    for name in free:
        if name not in PARAMETER_NAMES and name != "exposure" and name not in lights:
            raise FitResultError(f"{bad}: it frees {name!r}, of which it records no value")
    for name, sd in (fields.get("uncertainty") or {}).items():
        values = sd if isinstance(sd, list) else [sd]
        if not values or not all(_finite(v) for v in values) or len(values) not in (1, 3):
            raise FitResultError(f"{bad}: the uncertainty of {name!r} is not a finite number (or three)")
    correlation = fields.get("correlation") or {}
    if correlation:
        labels, matrix = correlation.get("labels"), correlation.get("matrix")
        if not (
            isinstance(labels, list)
            and isinstance(matrix, list)
            and len(matrix) == len(labels)
            and all(isinstance(row, list) and len(row) == len(labels) and all(map(_finite, row)) for row in matrix)
        ):
            raise FitResultError(f"{bad}: its correlation is not a square matrix of numbers with a label per row")
    exposure = data.get("exposure")
    if exposure is not None and not (_finite(exposure) and exposure > 0):
        raise FitResultError(f"{bad}: its exposure is not a positive finite number")


def nonfinite_entry(data: Any, where: str = "") -> tuple[str, float] | None:
    """Where the first NaN or infinite number in the JSON-like ``data`` (dicts, lists,
    numbers; NumPy values too) is, as a path (``uncertainty.color[0]``) and the value; None
    when every number is finite."""
    if isinstance(data, np.ndarray):
        return nonfinite_entry(data.tolist(), where)
    if isinstance(data, dict):
        items = ((f"{where}.{key}" if where else str(key), value) for key, value in data.items())
    elif isinstance(data, (list, tuple)):
        items = ((f"{where}[{index}]", value) for index, value in enumerate(data))
    elif isinstance(data, (float, np.floating)) and not math.isfinite(float(data)):
        return where, float(data)
    else:
        return None
    for path, value in items:
        found = nonfinite_entry(value, path)
        if found is not None:
            return found
    return None


def check_finite(data: Any, what: str = "the fit result") -> None:
    """Raise a one-line `FitResultError` naming the first NaN or infinite number in
    ``data`` (see `nonfinite_entry`): JSON holds neither (docs/formats.md), and a
    figure that is not a number is not passed on as one."""
    found = nonfinite_entry(data)
    if found is not None:
        where, value = found
        raise FitResultError(
            f"{what}'s {where} is {value}, not a finite number: a fit result never holds NaN or infinity"
        )


def finite_or_none(data: Any) -> Any:
    """``data`` (JSON-like) with every NaN or infinite number replaced by None (JSON's
    null): for figures where a non-finite value has a meaning, such as the cost of a start
    that diverged."""
    if isinstance(data, np.ndarray):
        return finite_or_none(data.tolist())
    if isinstance(data, dict):
        return {key: finite_or_none(value) for key, value in data.items()}
    if isinstance(data, (list, tuple)):
        return [finite_or_none(value) for value in data]
    if isinstance(data, (float, np.floating)) and not math.isfinite(float(data)):
        return None
    return data


@dataclass
class FitResult:
    """What a fit found; `to_json` follows docs/formats.md."""

    material: Material
    free: list[str]
    held: dict[str, dict[str, Any]] = field(default_factory=dict)
    lights: dict[str, float] = field(default_factory=dict)
    uncertainty: dict[str, Any] = field(default_factory=dict)
    correlation: dict[str, Any] = field(default_factory=dict)
    residual: dict[str, float] = field(default_factory=dict)
    solver: dict[str, Any] = field(default_factory=dict)
    starts: list[dict[str, Any]] = field(default_factory=list)
    start_spread: dict[str, float] = field(default_factory=dict)
    wall_time_s: float | None = None
    compile_and_solve: dict[str, float] = field(default_factory=dict)
    pixels_used: int | None = None
    notes: list[str] = field(default_factory=list)
    settings: dict[str, Any] = field(default_factory=dict)
    fitted_image: np.ndarray | None = None
    mask: np.ndarray | None = None
    #: The solved problem (entries pinned at bounds included) and the optimum ``x``
    #: (physical values in ``problem.layout`` order), for sampling and reports. None for a
    #: result read back with `from_json`. Its pixel set is padded (see
    #: `strauss_fit.fitting.problem.pixel_bucket`): ``problem.real(array)`` drops the
    #: padding from a per-pixel array, ``problem.unpadded()`` gives the problem without it.
    problem: Problem | None = None
    x: np.ndarray | None = None
    #: Other top-level keys of the JSON (``target``, ``scene``, ``mask``, ``encoding``
    #: recorded by the command line), written back by `to_json` after the rest.
    extra: dict[str, Any] = field(default_factory=dict)
    #: What the verdict found (``{"code", "message"}``, see `strauss_fit.fitting.diagnosis`).
    warnings: list[dict[str, str]] = field(default_factory=list)
    #: The global exposure: fitted with ``fit_exposure``, else the held value (1 unless fixed).
    exposure: float | None = None
    #: How `uncertainty` was computed and what it means (``name``: "noise sandwich" or
    #: "laplace"; ``conditional_on_model``: true when it is valid only if the model is right).
    uncertainty_method: dict[str, Any] = field(default_factory=dict)
    #: The Laplace deviations from RSS/(N − P), kept for comparison when `uncertainty`
    #: is the noise sandwich.
    uncertainty_laplace: dict[str, Any] = field(default_factory=dict)
    #: Perceptual equivalence ranges per free parameter (``fit(..., equivalence=True)``).
    equivalence: dict[str, Any] | None = None
    #: Flat indices of the pixels the fit used, and the residual there in noise units
    #: (RMS over channels; None when the noise is unknown), for the comparison image.
    used_index: np.ndarray | None = None
    standardized_residual: np.ndarray | None = None
    #: The target's linear pixels (H, W, 3) the fit saw (for the comparison image; not in
    #: the JSON).
    target_image: np.ndarray | None = None

    @property
    def at_bound(self) -> list[str]:
        """Labels of the entries the fit pinned on a bound."""
        return list(self.solver.get("at_bound", []))

    def value(self, name: str) -> Any:
        """The fitted or held value of a material parameter, a light intensity or the exposure."""
        if name in PARAMETER_NAMES:
            return self.material.to_dict()[name]
        if name == "exposure":
            return 1.0 if self.exposure is None else self.exposure
        return self.lights[name]

    @property
    def verdict(self) -> str | None:
        """``"consistent"``, ``"mismatch"`` or ``"undetermined"`` (see `strauss_fit.fitting.diagnosis`)."""
        return self.residual.get("verdict")

    def to_json(self) -> dict[str, Any]:
        """The result as ``strauss-fit fit`` writes it (docs/formats.md). Every number is
        finite: a NaN or infinite one raises a one-line `FitResultError` naming it
        (`check_finite`) rather than reaching a JSON writer."""
        out: dict[str, Any] = self.material.to_dict()
        out.update(
            {
                "free": self.free,
                "held": self.held,
                "uncertainty": self.uncertainty,
                "correlation": self.correlation,
                "residual": self.residual,
                "solver": self.solver,
                "starts": self.starts,
                "start_spread": self.start_spread,
                "lights": self.lights,
                "pixels_used": self.pixels_used,
                "wall_time_s": self.wall_time_s,
                "timing": self.compile_and_solve,
                "notes": self.notes,
                "settings": self.settings,
                "warnings": self.warnings,
                "uncertainty_method": self.uncertainty_method,
                "uncertainty_laplace": self.uncertainty_laplace,
            }
        )
        if self.exposure is not None:
            out["exposure"] = self.exposure
        if self.equivalence is not None:
            out["equivalence"] = self.equivalence
        out.update(self.extra)
        check_finite(out)
        return out

    @classmethod
    def from_json(cls, data: Any) -> FitResult:
        """Read back a result written by `to_json` (``strauss-fit fit``'s JSON).

        ``free`` and the material's values are required; the other fields default to
        empty. Keys that are not fields are kept in `extra`. Raises
        `FitResultError` (missing or malformed keys) or
        `MaterialError` (values out of range)."""
        if isinstance(data, FitResult):
            return data
        if not isinstance(data, dict):
            raise FitResultError("the fit result is not a strauss-fit fit result (not a JSON object)")
        try:
            if not isinstance(data["free"], list):  # a string would be read letter by letter
                raise TypeError("'free' is not a list")
            free = [str(n) for n in data["free"]]
            material_values = {k: data[k] for k in PARAMETER_NAMES}
            lights = {str(k): float(v) for k, v in (data.get("lights") or {}).items()}
            fields = {attribute: data[key] for key, attribute in _FIELDS.items() if key in data}
            for name in (
                "held",
                "uncertainty",
                "correlation",
                "residual",
                "solver",
                "start_spread",
                "settings",
                "uncertainty_method",
                "uncertainty_laplace",
            ):
                if not isinstance(fields.get(name, {}), dict):
                    raise TypeError(repr(name))
        except KeyError as exc:
            raise FitResultError(f"the fit result is not a strauss-fit fit result (missing or bad {exc})") from None
        except (TypeError, ValueError, AttributeError) as exc:
            raise FitResultError(f"the fit result is not a strauss-fit fit result (a bad value: {exc})") from None
        _check_recorded(data, free, lights, fields)
        fields.update(free=free, lights=lights)
        extra = {k: v for k, v in data.items() if k not in _FIELDS and k not in PARAMETER_NAMES}
        return cls(material=Material.from_dict(material_values), extra=extra, **fields)

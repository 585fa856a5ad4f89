r"""Parameter spaces of the models and how a dataset spec samples them.

Each model (`MODELS`) names its parameters, their shapes (a number, an RGB triple,
either, or a bool) and their ranges. The table is built from the registry of reflectance
models (`strauss_fit.models.reflectance.REFLECTANCE_MODELS`):

- ``"strauss"``: the registry's Strauss parameters (colour, smoothness, metalness,
  transparency, ior), rendered by the full (global) Strauss renderer;
- ``"phong"``: the classic Phong material of `strauss_fit.models.phong` (ka, kd, ks,
  exponent, diffuse_color, specular_color, blinn), rendered by its own renderer. The name
  is taken by it, so the registry's unnormalised Phong is not offered;
- every other registry model (``"lambert"``, ``"blinn-phong"``, ``"cook-torrance"``, and any
  added later): its parameters as the registry declares them (size 3: an RGB triple, size
  1: a number), rendered by `strauss_fit.rendering.reflectance.render_model`.

A dataset spec's ``[group.parameters]`` table gives each parameter as one *axis*:

- a fixed value: ``smoothness = 0.5``, ``color = [0.8, 0.3, 0.2]``, ``blinn = true``;
- a set of values: ``smoothness = [0.0, 0.5, 1.0]`` (scalars), ``color = [[1, 0, 0], [0, 1, 0]]``
  (colours), or explicitly ``{ values = [...] }`` (required for ``ka``/``kd``/``ks``, where a
  bare list of three numbers is one RGB value);
- a range: ``{ low = 0.0, high = 1.0 }`` with optional ``scale = "log"`` (log-uniform; needs
  low > 0) and, for a grid, ``steps = N`` (N equally spaced values, both ends included;
  geometrically spaced with ``scale = "log"``). ``low``/``high`` may be RGB triples for
  colour parameters (each channel drawn independently).

Parameters left out take the model's default (fixed).

Sampling:

- ``grid``: the Cartesian product of every axis's values, in the model's parameter order
  (the last parameter varying fastest). A range needs ``steps``.
- ``random``: ``count`` independent draws; a set draws one of its values uniformly, a range
  draws uniformly (or log-uniformly) in [low, high]. Before the draws come the *extremes*:
  every corner of the parameters named in ``extremes`` (each at the low and the high end of
  its axis; the other parameters drawn as usual). For Strauss ``extremes`` defaults to the
  varying ones of smoothness, metalness and transparency, so a random Strauss dataset over
  the full ranges always contains s, m, t at 0 and at 1; for the other models it defaults to none.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from strauss_fit import Material
from strauss_fit.errors import StraussFitError
from strauss_fit.models.material import FRACTION_NAMES
from strauss_fit.models.phong import MAX_EXPONENT, PhongMaterial
from strauss_fit.models.reflectance import REFLECTANCE_MODELS, reflectance_model
from strauss_fit.models.reflectance import Parameter as RegistryParameter

Shape = Literal["scalar", "rgb", "scalar_or_rgb", "bool"]
Value = Any  # float | list[float] | bool
#: Upper bound on the number of samples of one group (a typo in a grid must not fill a disk).
MAX_SAMPLES = 100_000


class SpecError(StraussFitError):
    """A dataset spec is missing, malformed, or asks for something impossible."""


@dataclass(frozen=True)
class Parameter:
    """One model parameter: its shape, its range [low, high] (``None``: unbounded on that
    side) and its default value."""

    name: str
    shape: Shape
    default: Value
    low: float | None = 0.0
    high: float | None = 1.0

    @property
    def span(self) -> str:
        low = "-inf" if self.low is None else f"{self.low:g}"
        return f"[{low}, {'inf' if self.high is None else f'{self.high:g}'}]"

    @classmethod
    def from_registry(cls, p: RegistryParameter) -> Parameter:
        """A registry parameter as synth reads it: size 3 an RGB triple, size 1 a number;
        its range and default (a number default of an RGB parameter fills every channel)."""
        if p.size == 3:
            default: Value = [float(c) for c in np.broadcast_to(np.asarray(p.default, dtype=float), (3,))]
        else:
            default = float(p.default)
        return cls(p.name, "rgb" if p.size == 3 else "scalar", default, p.low, p.high)


@dataclass(frozen=True)
class Model:
    """A lighting model: its parameters, how to build its material, default extremes."""

    name: str
    parameters: tuple[Parameter, ...]
    make_material: Callable[[dict[str, Value]], Any]
    default_extremes: tuple[str, ...]

    def parameter(self, name: str) -> Parameter:
        for p in self.parameters:
            if p.name == name:
                return p
        raise KeyError(name)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)


def _registry_parameters(name: str) -> tuple[Parameter, ...]:
    return tuple(Parameter.from_registry(p) for p in reflectance_model(name).parameters)


def _reflectance_values(name: str) -> Callable[[dict[str, Value]], dict[str, Value]]:
    """The "material" of a registry model: its values, checked by the model (every
    parameter given, each within its range), as the plain numbers and lists that
    `render_model` reads."""
    model = reflectance_model(name)

    def make(values: dict[str, Value]) -> dict[str, Value]:
        model.from_dict(values)
        return dict(values)

    return make


#: The models synth renders with their own renderers rather than the registry's local one:
#: Strauss with the global renderer (transparency, refraction), Phong as the classic material.
CLASSIC_MODELS = ("strauss", "phong")
#: The registry models that synth renders with `strauss_fit.rendering.reflectance.render_model`:
#: every one whose name no classic model takes (the registry's own Phong is not offered).
REFLECTANCE_SYNTH_MODELS = tuple(name for name in REFLECTANCE_MODELS if name not in CLASSIC_MODELS)

MODELS: dict[str, Model] = {
    "strauss": Model(
        "strauss",
        _registry_parameters("strauss"),
        Material.from_dict,
        FRACTION_NAMES,
    ),
    # A documented file format: existing specs and the bundled dataset name these
    # parameters, so it stays the classic material rather than the registry's Phong.
    "phong": Model(
        "phong",
        (
            Parameter("ka", "scalar_or_rgb", 1.0, high=None),
            Parameter("kd", "scalar_or_rgb", 0.7, high=None),
            Parameter("ks", "scalar_or_rgb", 0.3, high=None),
            Parameter("exponent", "scalar", 20.0, high=MAX_EXPONENT),
            Parameter("diffuse_color", "rgb", [1.0, 1.0, 1.0]),
            Parameter("specular_color", "rgb", [1.0, 1.0, 1.0]),
            Parameter("blinn", "bool", False),
        ),
        PhongMaterial.from_dict,
        (),
    ),
    **{
        name: Model(name, _registry_parameters(name), _reflectance_values(name), ())
        for name in REFLECTANCE_SYNTH_MODELS
    },
}


# --- axes -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Fixed:
    value: Value


@dataclass(frozen=True)
class Values:
    values: tuple[Value, ...]


@dataclass(frozen=True)
class Range:
    low: Value
    high: Value
    steps: int | None = None
    scale: Literal["linear", "log"] = "linear"


Axis = Fixed | Values | Range


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _is_rgb(v: Any) -> bool:
    return isinstance(v, list) and len(v) == 3 and all(_is_number(c) for c in v)


def _check_value(p: Parameter, value: Any, where: str) -> Value:
    """Validate one value of ``p`` and return it as plain floats (or a bool)."""
    if p.shape == "bool":
        if not isinstance(value, bool):
            raise SpecError(f"{where}: {p.name} must be true or false, got {value!r}")
        return value
    allowed = {"scalar": "a number", "rgb": "a list of 3 numbers", "scalar_or_rgb": "a number or a list of 3 numbers"}[
        p.shape
    ]
    ok = (_is_number(value) and p.shape in ("scalar", "scalar_or_rgb")) or (
        _is_rgb(value) and p.shape in ("rgb", "scalar_or_rgb")
    )
    if not ok:
        raise SpecError(f"{where}: {p.name} must be {allowed}, got {value!r}")
    numbers = [value] if _is_number(value) else value
    for x in numbers:
        if not math.isfinite(x) or (p.low is not None and x < p.low) or (p.high is not None and x > p.high):
            raise SpecError(f"{where}: {p.name} = {value!r} is outside its range {p.span}")
    return float(value) if _is_number(value) else [float(x) for x in value]


def parse_axis(p: Parameter, raw: Any, sampling: str, where: str) -> Axis:
    """Read one entry of a ``[group.parameters]`` table (see the module docstring)."""
    if isinstance(raw, dict):
        if "values" in raw:
            unknown = sorted(set(raw) - {"values"})
            if unknown:
                raise SpecError(f"{where}: {p.name}: a set takes only 'values', not {', '.join(unknown)}")
            return _parse_values(p, raw["values"], where)
        unknown = sorted(set(raw) - {"low", "high", "steps", "scale"})
        if unknown:
            raise SpecError(
                f"{where}: {p.name}: unknown key(s) {', '.join(unknown)}; a range takes low, high, "
                "steps, scale (or give values = [...])"
            )
        return _parse_range(p, raw, sampling, where)
    if isinstance(raw, list):
        if p.shape == "scalar" or p.shape == "bool":
            return _parse_values(p, raw, where)
        if raw and all(isinstance(v, list) for v in raw):
            return _parse_values(p, raw, where)
        if p.shape == "scalar_or_rgb" and not _is_rgb(raw):
            raise SpecError(
                f"{where}: {p.name}: a bare list is one RGB value here; write {{ values = [...] }} for a set of values"
            )
    return Fixed(_check_value(p, raw, where))


def _parse_values(p: Parameter, raw: Any, where: str) -> Values:
    if not isinstance(raw, list) or not raw:
        raise SpecError(f"{where}: {p.name}: values must be a non-empty list, got {raw!r}")
    return Values(tuple(_check_value(p, v, where) for v in raw))


def _parse_range(p: Parameter, raw: dict, sampling: str, where: str) -> Range:
    if p.shape == "bool":
        raise SpecError(f"{where}: {p.name} is true or false, not a range")
    for key in ("low", "high"):
        if key not in raw:
            raise SpecError(f"{where}: {p.name}: a range needs both low and high")
    low, high = raw["low"], raw["high"]
    if p.shape == "rgb":  # one number bounds every channel
        low, high = ([low] * 3 if _is_number(low) else low), ([high] * 3 if _is_number(high) else high)
    low, high = _check_value(p, low, where), _check_value(p, high, where)
    if isinstance(low, list) != isinstance(high, list) and p.shape == "scalar_or_rgb":
        low, high = (low if isinstance(low, list) else [low] * 3), (high if isinstance(high, list) else [high] * 3)
    if np.any(np.asarray(low) > np.asarray(high)):
        raise SpecError(f"{where}: {p.name}: low {low} is above high {high}")
    scale = raw.get("scale", "linear")
    if scale not in ("linear", "log"):
        raise SpecError(f"{where}: {p.name}: scale must be 'linear' or 'log', got {scale!r}")
    if scale == "log" and np.any(np.asarray(low) <= 0):
        raise SpecError(f"{where}: {p.name}: a log range needs low > 0, got {low}")
    steps = raw.get("steps")
    if sampling == "grid":
        if steps is None:
            raise SpecError(f'{where}: {p.name}: a range in a grid needs steps = N (or use sampling = "random")')
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise SpecError(f"{where}: {p.name}: steps must be an integer >= 1, got {steps!r}")
        if isinstance(low, list) or p.shape == "rgb":
            raise SpecError(
                f"{where}: {p.name}: a colour range can only be drawn at random; "
                "list the colours in values = [...] for a grid"
            )
        if steps == 1 and low != high:
            raise SpecError(f"{where}: {p.name}: steps = 1 needs low == high")
    elif steps is not None:
        raise SpecError(f'{where}: {p.name}: steps only applies to sampling = "grid"')
    return Range(low, high, steps, scale)


# --- expansion --------------------------------------------------------------------------


def grid_values(axis: Axis) -> list[Value]:
    """The values an axis contributes to a grid."""
    if isinstance(axis, Fixed):
        return [axis.value]
    if isinstance(axis, Values):
        return list(axis.values)
    assert axis.steps is not None
    if axis.steps == 1:
        return [axis.low]
    space = np.geomspace if axis.scale == "log" else np.linspace
    points = space(axis.low, axis.high, axis.steps)
    points[0], points[-1] = axis.low, axis.high
    return [float(np.clip(x, axis.low, axis.high)) for x in points]


def grid_size(axes: dict[str, Axis]) -> int:
    return math.prod(len(grid_values(a)) for a in axes.values())


def expand_grid(model: Model, axes: dict[str, Axis]) -> list[dict[str, Value]]:
    """Every combination of the axes' values, in the model's parameter order."""
    names = model.names
    return [dict(zip(names, combo)) for combo in itertools.product(*(grid_values(axes[n]) for n in names))]


def _draw(axis: Axis, rng: np.random.Generator) -> Value:
    if isinstance(axis, Fixed):
        return axis.value
    if isinstance(axis, Values):
        return axis.values[int(rng.integers(len(axis.values)))]
    low, high = np.asarray(axis.low, dtype=float), np.asarray(axis.high, dtype=float)
    u = rng.random(low.shape)
    if axis.scale == "log":
        x = np.exp(np.log(low) + (np.log(high) - np.log(low)) * u)
    else:
        x = low + (high - low) * u
    x = np.clip(x, low, high)
    return float(x) if x.ndim == 0 else [float(c) for c in x]


def axis_ends(axis: Axis) -> tuple[Value, Value]:
    """The low and high end of a scalar axis (a set's smallest and largest value)."""
    if isinstance(axis, Fixed):
        return axis.value, axis.value
    if isinstance(axis, Values):
        return min(axis.values), max(axis.values)
    return axis.low, axis.high


def expand_random(
    model: Model, axes: dict[str, Axis], count: int, extremes: tuple[str, ...], rng: np.random.Generator
) -> list[dict[str, Value]]:
    """The corners of ``extremes`` (others drawn), then ``count`` independent draws."""
    corners = [()]
    if extremes:
        ends = [sorted(set(axis_ends(axes[n])), key=float) for n in extremes]
        corners = list(itertools.product(*ends))
    samples = []
    if extremes:
        for corner in corners:
            values = {n: _draw(axes[n], rng) for n in model.names}
            values.update(dict(zip(extremes, corner)))
            samples.append(values)
    for _ in range(count):
        samples.append({n: _draw(axes[n], rng) for n in model.names})
    return samples

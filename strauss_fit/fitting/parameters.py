r"""Fit parameters: which quantities are free, their ranges, and smooth transforms.

A fit works on an unconstrained vector θ. Each free quantity maps to its physical value
through a smooth transform that keeps it in range without clipping (the transforms of
MINUIT, which reach the bounds at finite θ):

- a value in [0, 1] (colour channels, smoothness, metalness, transparency):
  `x = (1 + \sin\theta)/2`;
- a value with only a lower bound ``low`` (index of refraction ≥ 1, light intensity and
  the global exposure ≥ 0):
  `x = \mathrm{low} - 1 + \sqrt{\theta^2 + 1}`.

Uncertainties are always computed for the physical values, never for θ.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import jax.numpy as jnp
import numpy as np
from jax import Array

from ..models.material import STRAUSS_PARAMETERS, Material
from ..numerics import device_array
from ..scene.lights import Lights

#: The material parameters a fit can free, and their entries in the vector θ (the colour 3).
MATERIAL_SIZES = {p.name: p.size for p in STRAUSS_PARAMETERS}
UNIT_INTERVAL = "unit"
LOWER_BOUNDED = "lower"


def light_parameter_names(lights: Lights) -> list[str]:
    """Names of the light intensities a fit can free: ``directional_intensity_1``,
    ``point_intensity_1``, ... (in scene-file order within each kind) and ``ambient_intensity``."""
    names = [f"{kind.KIND}_intensity_{i + 1}" for kind in lights.present() for i in range(kind.intensity.shape[0])]
    if lights.ambient is not None:
        names.append("ambient_intensity")
    return names


def _kind_and_low(name: str) -> tuple[str, float]:
    if name == "ior":
        return LOWER_BOUNDED, 1.0
    if name.endswith("intensity") or "_intensity_" in name or name == "exposure":
        return LOWER_BOUNDED, 0.0
    return UNIT_INTERVAL, 0.0


@dataclass(frozen=True)
class Layout:
    """The free parameters, in order, and where each sits in the vector θ.

    ``names`` are parameter groups (``color`` has 3 entries, the others 1).
    """

    names: tuple[str, ...]
    sizes: tuple[int, ...] = field(init=False)
    offsets: tuple[int, ...] = field(init=False)

    def __post_init__(self):
        sizes = tuple(MATERIAL_SIZES.get(n, 1) for n in self.names)
        offsets = tuple(int(v) for v in np.cumsum((0,) + sizes[:-1]))
        object.__setattr__(self, "sizes", sizes)
        object.__setattr__(self, "offsets", offsets)

    @property
    def size(self) -> int:
        return int(sum(self.sizes))

    def labels(self) -> list[str]:
        """One label per vector entry (``color_r``, ``color_g``, ``color_b``, ...)."""
        out = []
        for name, size in zip(self.names, self.sizes):
            out += [f"{name}_{c}" for c in "rgb"] if size == 3 else [name]
        return out

    def split(self, vector: Array) -> dict[str, Array]:
        """The entries of a vector by parameter (scalars for size-1 groups)."""
        out = {}
        for name, size, offset in zip(self.names, self.sizes, self.offsets):
            part = vector[..., offset : offset + size]
            out[name] = part if size > 1 else part[..., 0]
        return out

    def join(self, values: dict[str, Any]) -> np.ndarray:
        """The inverse of `split`, for concrete values."""
        return (
            np.concatenate([np.atleast_1d(np.asarray(values[n], dtype=np.float64)) for n in self.names])
            if self.names
            else np.zeros(0)
        )

    def to_physical(self, theta: Array) -> Array:
        """Apply each entry's transform (see the module docstring)."""
        parts = []
        for name, size, offset in zip(self.names, self.sizes, self.offsets):
            t = theta[..., offset : offset + size]
            kind, low = _kind_and_low(name)
            parts.append((1 + jnp.sin(t)) / 2 if kind == UNIT_INTERVAL else low - 1 + jnp.sqrt(t * t + 1))
        return jnp.concatenate(parts, axis=-1) if parts else theta

    def to_physical_numpy(self, theta: np.ndarray) -> np.ndarray:
        """`to_physical` in NumPy, for concrete values outside a compiled function."""
        theta = np.asarray(theta, dtype=np.float64)
        parts = []
        for name, size, offset in zip(self.names, self.sizes, self.offsets):
            t = theta[..., offset : offset + size]
            kind, low = _kind_and_low(name)
            parts.append((1 + np.sin(t)) / 2 if kind == UNIT_INTERVAL else low - 1 + np.sqrt(t * t + 1))
        return np.concatenate(parts, axis=-1) if parts else theta

    def to_unconstrained(self, physical: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """A θ mapping to ``physical`` (first clipped ``margin`` inside [0, 1] for unit
        entries, since the transform's slope vanishes on the bounds)."""
        physical = np.asarray(physical, dtype=np.float64)
        out = np.empty_like(physical)
        for name, size, offset in zip(self.names, self.sizes, self.offsets):
            x = physical[..., offset : offset + size]
            kind, low = _kind_and_low(name)
            if kind == UNIT_INTERVAL:
                out[..., offset : offset + size] = np.arcsin(np.clip(2 * np.clip(x, margin, 1 - margin) - 1, -1, 1))
            else:
                shifted = np.maximum(x - low, margin) + 1
                out[..., offset : offset + size] = np.sqrt(shifted**2 - 1)
        return out

    def lower_bounds(self) -> np.ndarray:
        return (
            np.concatenate([np.full(s, _kind_and_low(n)[1]) for n, s in zip(self.names, self.sizes)])
            if self.names
            else np.zeros(0)
        )

    def upper_bounds(self) -> np.ndarray:
        return (
            np.concatenate(
                [
                    np.full(s, 1.0 if _kind_and_low(n)[0] == UNIT_INTERVAL else np.inf)
                    for n, s in zip(self.names, self.sizes)
                ]
            )
            if self.names
            else np.zeros(0)
        )


def material_with(base: Material, values: dict[str, Array]) -> Material:
    """``base`` with the material parameters in ``values`` replaced (no validation: the
    values may be traced)."""
    fields = {name: getattr(base, name) for name in MATERIAL_SIZES}
    fields.update({k: v for k, v in values.items() if k in MATERIAL_SIZES})
    material = object.__new__(Material)
    for name, value in fields.items():
        object.__setattr__(material, name, device_array(value))
    return material


def lights_with(base: Lights, values: dict[str, Array]) -> Lights:
    """``base`` with the intensities named as in `light_parameter_names` replaced."""
    intensities = {}
    for kind in ("directional", "point"):
        group = getattr(base, kind)
        if group is None:
            continue
        current = group.intensity
        for i in range(current.shape[0]):
            key = f"{kind}_intensity_{i + 1}"
            if key in values:
                current = current.at[i].set(values[key])
        intensities[kind] = current
    if base.ambient is not None and "ambient_intensity" in values:
        intensities["ambient"] = values["ambient_intensity"]
    return base.with_intensities(intensities)


def intensity_vector(lights: Lights) -> Any:
    """The directional then point intensities as one vector (None without such lights)."""
    parts = [kind.intensity for kind in lights.present()]
    return jnp.concatenate(parts) if parts else None


def all_intensities(lights: Lights) -> list[float]:
    """Every intensity as a float, in `light_parameter_names` order."""
    values = []
    vector = intensity_vector(lights)
    if vector is not None:
        values += [float(v) for v in np.asarray(vector)]
    if lights.ambient is not None:
        values.append(float(np.asarray(lights.ambient)))
    return values


def value_of(name: str, material: Material, lights: Lights, exposure: float = 1.0) -> Any:
    """The current value of parameter ``name`` (a material parameter, a light intensity,
    or the global ``exposure``)."""
    if name in MATERIAL_SIZES:
        return material.to_dict()[name]
    if name == "exposure":
        return float(exposure)
    return dict(zip(light_parameter_names(lights), all_intensities(lights)))[name]


def jsonable(values: dict[str, Any]) -> dict[str, Any]:
    """Concrete parameter values (as from `Layout.split`) as floats and lists of floats."""
    out = {}
    for k, v in values.items():
        arr = np.asarray(v)
        out[k] = arr.tolist() if arr.ndim else float(arr)
    return out

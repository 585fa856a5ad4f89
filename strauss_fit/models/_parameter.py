"""One parameter of a shading model: `Parameter`, its name, size, range and default.

A module of its own, importing nothing of the package's models: the Strauss material
(`strauss_fit.models.material`) defines its parameters with it, and the reflectance
models (`strauss_fit.models.reflectance`, which import the material) take them from
there; `strauss_fit.models.reflectance` re-exports it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

UNIT, POSITIVE, FREE = "unit", "positive", "free"


@dataclass(frozen=True)
class Parameter:
    """One parameter of a reflectance model.

    ``size`` is 1 (a number) or 3 (an RGB triple); ``low`` and ``high`` bound every channel
    (``None``: unbounded on that side); ``default`` is a number (for RGB: every channel) or a
    triple; ``doc`` says in one line what the parameter is and ``needs`` what a scene must
    show for it to be identifiable.
    """

    name: str
    size: int
    low: float | None
    high: float | None
    default: float | tuple[float, float, float]
    doc: str
    needs: str

    def __post_init__(self):
        if self.size not in (1, 3):
            raise ValueError(f"parameter {self.name}: size must be 1 or 3, got {self.size}")
        if self.low is None and self.high is not None:
            raise ValueError(f"parameter {self.name}: an upper bound needs a lower bound")
        if self.low is not None and self.high is not None and not self.low < self.high:
            raise ValueError(f"parameter {self.name}: empty range [{self.low}, {self.high}]")
        default = np.broadcast_to(np.asarray(self.default, dtype=float), (self.size,))
        if not self.contains(default):
            raise ValueError(f"parameter {self.name}: default {self.default} outside {self.span}")

    @property
    def kind(self) -> str:
        """How a fit maps the parameter: ``"unit"`` when bounded on both sides (usually [0, 1]),
        ``"positive"`` when bounded below only (usually [0, ∞)), ``"free"`` when unbounded."""
        if self.low is None:
            return FREE
        return POSITIVE if self.high is None else UNIT

    @property
    def span(self) -> str:
        """The range as text, e.g. ``[0, 1]`` or ``[0, inf)``."""
        low = "-inf" if self.low is None else f"{self.low:g}"
        return f"[{low}, inf)" if self.high is None else f"[{low}, {self.high:g}]"

    def contains(self, value: Any) -> bool:
        """Whether every channel of ``value`` is finite and within the range."""
        try:
            arr = np.asarray(value, dtype=float)
        except (OverflowError, TypeError, ValueError):  # an integer beyond float64 (JSON allows 10**400)
            return False
        inside = np.isfinite(arr)
        if self.low is not None:
            inside &= arr >= self.low
        if self.high is not None:
            inside &= arr <= self.high
        return bool(np.all(inside))

    def clip(self, value: ArrayLike) -> Array:
        """``value`` clipped to the range (channel by channel)."""
        return jnp.clip(jnp.asarray(value), self.low, self.high)

    def default_value(self) -> Array:
        """The default as an array: shape () for a number, (3,) for RGB."""
        value = jnp.asarray(self.default, dtype=float)
        return value if self.size == 1 else jnp.broadcast_to(value, (3,))

r"""A simple camera sensor: exposure, shot noise, read noise, and 8-bit sRGB encoding.

For a rendered linear radiance L (per pixel and channel) the recorded linear value is

```text
E = k\,L, \qquad
S = \begin{cases} P/g,\ P \sim \mathrm{Poisson}(g \max(E, 0)) & g > 0 \\ E & g = 0 \end{cases},
\qquad O = S + \varepsilon,\ \varepsilon \sim \mathcal N(0, \sigma^2),
```

with k the ``exposure`` scale, g the ``gain`` (photons per unit of exposed radiance, the
photon scale of the shot noise; 0 switches shot noise off) and σ the ``read_noise``
standard deviation (in the same units as E; 0 switches it off). Every pixel and channel,
background included, is independent, and for E ≥ 0

```text
\mathbb E[O] = E, \qquad \operatorname{Var}[O] = E/g + \sigma^2 .
```

The noise comes from the `numpy.random.Generator` passed in (Poisson draws first,
then the Gaussian draws, both in C order), so a seed fixes it bit for bit.

LDR output (`encode_ldr`): O is clipped to [0, 1], sRGB-encoded with colour-science
(`strauss_fit.color.srgb_encode`) and rounded to 8 bits. A pixel is *clipped* where any
channel has the top code 255: its true value is unknown (at or above the code's lower
edge), exactly the rule `strauss_fit.io.images.read_image` applies when reading an LDR
image. Values below 0 become code 0 and are not marked.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from strauss_fit.color import srgb_encode

from .params import SpecError

#: Upper bound on the gain (keeps Poisson means far inside numpy's range).
MAX_GAIN = 1e9


@dataclass(frozen=True)
class Sensor:
    """Exposure scale k, shot-noise gain g (0: off) and read-noise σ (0: off)."""

    exposure: float = 1.0
    gain: float = 0.0
    read_noise: float = 0.0

    def __post_init__(self) -> None:
        for name, low_open in (("exposure", True), ("gain", False), ("read_noise", False)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise SpecError(f"sensor {name} must be a finite number, got {value!r}")
            if value < 0 or (low_open and value == 0):
                raise SpecError(f"sensor {name} = {value} must be {'>' if low_open else '>='} 0")
        if self.gain > MAX_GAIN:
            raise SpecError(f"sensor gain = {self.gain} must be <= {MAX_GAIN:g}")

    @property
    def noisy(self) -> bool:
        """Whether the sensor adds any noise."""
        return self.gain > 0 or self.read_noise > 0

    def apply(self, radiance: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The recorded linear image O (float64) for a linear radiance image."""
        exposed = np.asarray(radiance, dtype=np.float64) * float(self.exposure)
        if self.gain > 0:
            photons = rng.poisson(np.maximum(exposed, 0.0) * self.gain)
            exposed = photons.astype(np.float64) / self.gain
        if self.read_noise > 0:
            exposed = exposed + rng.normal(0.0, self.read_noise, size=exposed.shape)
        return exposed

    def expected_variance(self, exposed: np.ndarray | float) -> np.ndarray:
        """Var[O] = E/g + σ² for the exposed radiance E (≥ 0)."""
        shot = np.asarray(exposed, dtype=np.float64) / self.gain if self.gain > 0 else 0.0
        return shot + self.read_noise**2

    def to_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, values: dict[str, Any], where: str = "") -> Sensor:
        """Build from a ``[group.sensor]`` table; ``where`` prefixes error messages."""
        prefix = f"{where}: " if where else ""
        unknown = sorted(set(values) - {"exposure", "gain", "read_noise"})
        if unknown:
            raise SpecError(f"{prefix}unknown sensor key(s) {', '.join(unknown)}; allowed: exposure, gain, read_noise")
        try:
            return cls(**values)
        except SpecError as exc:
            raise SpecError(f"{prefix}{exc}") from None


def encode_ldr(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """8-bit sRGB codes (H, W, 3) uint8 of a linear image, and the clipped mask (H, W):
    true where any channel's code is 255."""
    codes = np.round(srgb_encode(image) * 255.0).astype(np.uint8)
    return codes, np.any(codes == 255, axis=-1)

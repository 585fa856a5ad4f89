r"""The energy-normalised Blinn–Phong model."""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar, final

import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from ...precision import uses_float64
from ..phong import highlight_power, phong_angles
from ._base import Parameter, power_lobe_width, scalar
from ._lobe import DiffuseLobeModel


@final
class BlinnPhong(DiffuseLobeModel):
    r"""Normalised Blinn–Phong: the BRDF
    `f_r = k_d/\pi + k_s\,\frac{e + 8}{8\pi}\,(N\cdot H)^e`, H = (L + V)/|L + V|, so

    ```text
    L = k_d\cos\alpha + k_s\,\frac{e + 8}{8}\,(N\cdot H)^e\cos\alpha.
    ```

    Reciprocal. The factor (e + 8)/(8π) is the usual approximation of the normalisation;
    with `k_d + k_s \le 1` the albedo stays within a few per cent of 1 but is not
    bounded by it (the tests measure it). This differs from the capture fitter's
    ``"blinn-phong"``, which is unnormalised (`k_s (N\cdot H)^e`, no cos α), and from
    `phong_shade` with ``blinn=True`` (the same, unnormalised).
    Ambient: `k_d`.
    """

    name: ClassVar[str] = "blinn-phong"
    parameters: ClassVar[tuple[Parameter, ...]] = (
        Parameter(
            "diffuse",
            3,
            0.0,
            None,
            0.7,
            "k_d: the diffuse albedo (linear RGB; times the image scale)",
            "a lit surface in view",
        ),
        Parameter(
            "specular",
            1,
            0.0,
            None,
            0.3,
            "k_s: the highlight's share of the reflected light (white; times the image scale)",
            "a highlight in view",
        ),
        Parameter(
            "exponent",
            1,
            0.0,
            None,
            80.0,
            "e: the exponent of N·H (larger is narrower; about 4× a Phong exponent)",
            "a highlight in view, resolved over a few pixels (its width)",
        ),
    )
    bounded_scale: ClassVar[bool] = False
    nonlinear: ClassVar[tuple[str, ...]] = ("exponent",)

    @uses_float64
    def terms(self, normal: ArrayLike, to_light: ArrayLike, view: ArrayLike) -> dict[str, Array]:
        """``lit``, ``cos_alpha`` and ``cos_nh`` (N·H clamped to [0, 1]; 0 where not lit)."""
        lit, cos_alpha, cos_nh = phong_angles(normal, to_light, view, blinn=True)
        return {"lit": lit, "cos_alpha": cos_alpha, "cos_nh": jnp.where(lit, cos_nh, 0.0)}

    def _lobe(self, exponent: ArrayLike, terms: Mapping[str, Array]) -> Array:
        e = scalar(exponent)
        power = highlight_power(terms["cos_nh"], e)
        return jnp.where(terms["lit"], (e + 8) / 8 * power * terms["cos_alpha"], 0.0)

    def start_grid(self) -> list[dict[str, float]]:
        """Exponents geomspace(4, 20000, 14): the Phong grid's lobes (e ≈ 4n for the same width)."""
        return [{"exponent": float(n)} for n in np.geomspace(4.0, 20000.0, 14)]

    def _albedo_lobe(self, x: Mapping[str, Array], cos_in: Array) -> tuple[str, Array]:
        return "half", power_lobe_width(scalar(x["exponent"]))

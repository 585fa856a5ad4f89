r"""Phong's model as the capture fitter uses it: a coloured diffuse part and a white highlight."""

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
class Phong(DiffuseLobeModel):
    r"""`L = k_d\cos\alpha + k_s\max(\cos\beta, 0)^n`, cos β = R·V with R the mirror
    direction of L: the capture fitter's Phong, and
    `phong_shade` with `k_d C_d` = ``diffuse`` and
    `k_s C_{sp}` = ``specular`` (white). Not normalised: the highlight is not
    multiplied by cos α and its peak does not narrow with n, so the model is not reciprocal
    (its BRDF `k_s\cos^n\beta/(\pi\cos\alpha)` is not symmetric in L and V) and creates
    energy towards grazing incidence. Ambient: `k_d`.
    """

    name: ClassVar[str] = "phong"
    parameters: ClassVar[tuple[Parameter, ...]] = (
        Parameter(
            "diffuse",
            3,
            0.0,
            None,
            0.7,
            "k_d: the diffuse coefficient (linear RGB; times the image scale)",
            "a lit surface in view",
        ),
        Parameter(
            "specular",
            1,
            0.0,
            None,
            0.3,
            "k_s: the strength of the white highlight (times the image scale)",
            "a highlight in view",
        ),
        Parameter(
            "exponent",
            1,
            0.0,
            None,
            20.0,
            "n: the highlight exponent (larger is narrower)",
            "a highlight in view, resolved over a few pixels (its width)",
        ),
    )
    bounded_scale: ClassVar[bool] = False
    nonlinear: ClassVar[tuple[str, ...]] = ("exponent",)

    @uses_float64
    def terms(self, normal: ArrayLike, to_light: ArrayLike, view: ArrayLike) -> dict[str, Array]:
        """``lit``, ``cos_alpha`` and ``cos_beta`` (R·V clamped to [0, 1]; 0 where not lit)."""
        lit, cos_alpha, cos_beta = phong_angles(normal, to_light, view, blinn=False)
        return {"lit": lit, "cos_alpha": cos_alpha, "cos_beta": jnp.where(lit, cos_beta, 0.0)}

    def _lobe(self, exponent: ArrayLike, terms: Mapping[str, Array]) -> Array:
        return jnp.where(terms["lit"], highlight_power(terms["cos_beta"], scalar(exponent)), 0.0)

    def start_grid(self) -> list[dict[str, float]]:
        """Exponents geomspace(2, 5000, 14), the capture fitter's."""
        return [{"exponent": float(n)} for n in np.geomspace(2.0, 5000.0, 14)]

    def _albedo_lobe(self, x: Mapping[str, Array], cos_in: Array) -> tuple[str, Array]:
        return "mirror", power_lobe_width(scalar(x["exponent"]))

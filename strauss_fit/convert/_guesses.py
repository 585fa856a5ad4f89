r"""Closed-form guesses both conversion directions start from.

- `strauss_guess`: Strauss parameters for a Phong material (the Phong → Strauss
  fit's first start, `strauss_fit.convert._to_strauss`);
- `phong_guess`: Phong's identifiable parameters for a Strauss material (the
  Strauss → Phong fit's first start, `strauss_fit.convert._to_phong`);
- `metallic_tint`: whether a Phong highlight is tinted, which decides the canonical
  branch (metal or dielectric) of a Phong → Strauss conversion.

Public through `strauss_fit.convert.converter`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..models.material import Material
from ..models.phong import MAX_EXPONENT, PhongMaterial
from ..models.strauss import K_J, fresnel, shadow
from .phong_fit import unit_from_exponent

#: Angle (α = γ) at which the closed-form Strauss → Phong guess evaluates j and F.
GUESS_ANGLE_DEG = 30.0


def triple(value: Any) -> np.ndarray:
    """``value`` (a scalar or an RGB triple) as a float64 RGB triple (a fresh array)."""
    return np.broadcast_to(np.asarray(value, dtype=np.float64), (3,)).copy()


def strauss_guess(phong: PhongMaterial) -> tuple[dict[str, Any], list[str]]:
    r"""Closed-form Strauss parameters for a Phong material (the fit's first start).

    With `D = k_d C_d` and `S = k_s C_{sp}` (RGB) and the exponent n:

    - smoothness from the lobe width: Strauss's highlight is `\cos^h\beta` with
      `h = 3/(1 - s)`, Phong's `\cos^n\beta`, so `s = 1 - 3/n`, clipped to
      [0, 1) (n ≤ 3 gives s = 0: Strauss has no lobe wider than h = 3). For Blinn–Phong,
      whose `\cos^n(N\cdot H)` is close to `\cos^{n/4}(R\cdot V)`, n/4 is used.
      For a pure Phong lobe the guessed s reproduces the lobe's shape exactly. Without a
      highlight (S = 0) s = 0, whatever n says.
    - metalness from the tint of the highlight: Strauss's highlight colour at small
      angles of incidence is `C_s \approx (1 - m)\,\mathrm{white} + m\,C`, so with
      `\hat C = D/\max D` (the diffuse hue) and the tint `T = S/\max S`,
      `m = (1 - \min T)/(1 - \min\hat C)`, clipped to [0, 1]; a white highlight gives
      m = 0, and so does a grey diffuse colour (no hue to compare with). Without a diffuse
      term (D = 0) a tinted highlight means a metal of that colour (m = 1, C = T), a
      white one a black dielectric (m = 0, C = 0), and no highlight either Strauss's
      darkest material (C = 0, m = 1, s = 0: its off-specular term never vanishes).
    - colour from the diffuse term: Strauss's diffuse reflectance is
      `(1 - ms)(1 - s^3)\,C`, so `C = D / ((1 - ms)(1 - s^3))`; where that
      exceeds 1 it is scaled down to a largest channel of 1 (keeping the hue), with a note.

    Phong's ks has no Strauss counterpart of its own: the highlight's strength follows
    from s (`r_n = s^3`) and m. Returns the guess and notes.
    """
    notes: list[str] = []
    d = triple(phong.kd) * np.asarray(phong.diffuse_color, dtype=np.float64)
    s_rgb = triple(phong.ks) * np.asarray(phong.specular_color, dtype=np.float64)
    n = float(phong.exponent)
    n_lobe = n / 4.0 if phong.blinn else n
    d_max, s_max = float(d.max()), float(s_rgb.max())
    if s_max > 0:
        smoothness = float(np.clip(1.0 - 3.0 / n_lobe, 0.0, 1.0)) if n_lobe > 0 else 0.0
        smoothness = min(smoothness, float(np.nextafter(1.0, 0.0)))
    else:
        smoothness = 0.0  # no highlight: the matte end (any s > 0 would add one)
    tint = s_rgb / s_max if s_max > 0 else np.ones(3)
    tinted = 1.0 - float(tint.min()) > 0.05
    if d_max <= 1e-12:
        if s_max > 0 and tinted:
            metalness, color = 1.0, tint
        elif s_max > 0:
            metalness, color = 0.0, np.zeros(3)
        else:  # black: Strauss's darkest material (its off-specular term k_j j F never vanishes)
            metalness, color = 1.0, np.zeros(3)
    else:
        hue = d / d_max
        chroma = 1.0 - float(hue.min())
        metalness = float(np.clip((1.0 - float(tint.min())) / chroma, 0.0, 1.0)) if chroma > 0.05 and s_max > 0 else 0.0
        scale = (1.0 - metalness * smoothness) * (1.0 - smoothness**3)
        color = d / scale if scale > 1e-12 else hue
        if color.max() > 1.0:
            notes.append(
                f"the diffuse term kd·Cd = {np.round(d, 4).tolist()} is brighter than Strauss allows at "
                f"s = {smoothness:.3f}, m = {metalness:.3f}; the guessed colour is scaled to a largest channel of 1"
            )
            color = color / color.max()
    guess = {"color": [float(c) for c in np.clip(color, 0.0, 1.0)], "smoothness": smoothness, "metalness": metalness}
    return guess, notes


def phong_guess(material: Material) -> tuple[np.ndarray, float]:
    r"""Closed-form Phong parameters for an (opaque) Strauss material: the vector
    (D, S, u) of `strauss_fit.convert.phong_fit.PHONG_LAYOUT` and the ambient coefficient.

    - n = h = 3/(1 − s) (clipped to [1, 10000]; s = 1 gives 10000);
    - D = (1 − ms)(1 − s³) C, Strauss's diffuse reflectance;
    - S = r_j C_s evaluated at α = γ = `GUESS_ANGLE_DEG` (j and F there), with
      `r_j = \min(1, r_n + j(r_n + k_j))`, `r_n = s^3`;
    - ka = (1 − s³)·max C, so that Phong's ambient term `k_a C_d` with
      `C_d = D/\max D` equals Strauss's `r_d C` (exactly when the diffuse hue
      is C's, which it always is).
    """
    c = np.asarray(material.color, dtype=np.float64)
    s, m = float(material.smoothness), float(material.metalness)
    h = 3.0 / (1.0 - s) if s < 1 else MAX_EXPONENT
    d = (1.0 - m * s) * (1.0 - s**3) * c
    x = 2.0 * math.radians(GUESS_ANGLE_DEG) / math.pi
    f, g = float(fresnel(x)), float(shadow(x))
    r_n = s**3
    r_j = min(1.0, r_n + f * g * g * (r_n + K_J))
    spec = r_j * (1.0 + m * (1.0 - f) * (c - 1.0))
    vector = np.concatenate([np.clip(d, 0, 1), np.clip(spec, 0, 1), [unit_from_exponent(h)]])
    return vector, float((1.0 - s**3) * c.max())


def metallic_tint(phong: PhongMaterial) -> bool:
    """Whether a Phong material's highlight is tinted — what a metal shows (its colour
    differs from white by more than 5 %, as `strauss_guess` reads it)."""
    specular = triple(phong.ks) * np.asarray(phong.specular_color, dtype=np.float64)
    top = float(specular.max())
    return top > 0 and 1.0 - float(specular.min()) / top > 0.05

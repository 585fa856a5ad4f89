"""Colour: the sRGB transfer functions and CIEDE2000 colour differences.

sRGB (IEC 61966-2-1): `srgb_decode` takes 8-bit style encoded values in [0, 1] to
linear radiance, `srgb_encode` the reverse (clipping to [0, 1] first).

CIEDE2000 (`delta_e_2000`): both images are read as linear sRGB (D65). HDR values
are first divided by a common scale, the larger of 1 and the reference's 99th-percentile
value, so that the difference is the one seen on a display exposed for the reference; the
values are then clipped to [0, 1], converted to CIE XYZ (sRGB's matrix) and CIE L*a*b*
(D65 white) and compared with ΔE2000 (Sharma, Wu & Dalal 2005).

Written out in NumPy rather than called from colour-science, with which the tests check
that it agrees to 1e-10 (tests/test_color.py): importing colour-science takes about a
second, a third of a single fit's whole budget on the command line, and the fit needs
these few formulas on every call.
"""

from __future__ import annotations

import math

import numpy as np

#: sRGB's linear-RGB-to-XYZ matrix (IEC 61966-2-1, as colour-science's sRGB colourspace).
SRGB_TO_XYZ = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
#: The D65 white (x, y) = (0.3127, 0.3290) as XYZ with Y = 1.
D65_WHITE = np.array([0.3127 / 0.3290, 1.0, (1.0 - 0.3127 - 0.3290) / 0.3290])
#: Where the two pieces of the sRGB curve meet, in linear and in encoded values.
_SRGB_LINEAR_KNEE = 0.0031308
_SRGB_ENCODED_KNEE = 1.055 * _SRGB_LINEAR_KNEE ** (1 / 2.4) - 0.055


def srgb_decode(values: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] to linear (IEC 61966-2-1)."""
    v = np.asarray(values, dtype=np.float64)
    return np.where(v <= _SRGB_ENCODED_KNEE, v / 12.92, np.power((np.maximum(v, 0.0) + 0.055) / 1.055, 2.4))


def srgb_encode(values: np.ndarray) -> np.ndarray:
    """Linear values to sRGB-encoded values; the input is clipped to [0, 1] first."""
    x = np.clip(np.asarray(values, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= _SRGB_LINEAR_KNEE, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def linear_to_lab(values: np.ndarray) -> np.ndarray:
    """Linear sRGB (..., 3) in [0, 1] to CIE L*a*b* (D65)."""
    xyz = np.asarray(values, dtype=np.float64) @ SRGB_TO_XYZ.T / D65_WHITE
    epsilon, kappa = 216 / 24389, 24389 / 27
    f = np.where(xyz > epsilon, np.cbrt(xyz), (kappa * xyz + 16) / 116)
    return np.stack([116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]), 200 * (f[..., 1] - f[..., 2])], axis=-1)


#: cos and sin of the phase shifts of CIEDE2000's hue weighting T (30°, 6°, 63°).
_T_PHASES = {degrees: (math.cos(math.radians(degrees)), math.sin(math.radians(degrees))) for degrees in (30, 6, 63)}
_POW25_7 = 25.0**7


def _seventh(x: np.ndarray) -> np.ndarray:
    """x⁷ by multiplications (``x**7`` is a general power: several times slower)."""
    square = x * x
    return square * square * square * x


def ciede2000(lab1: np.ndarray, lab2: np.ndarray) -> np.ndarray:
    """ΔE2000 between CIE L*a*b* colours (..., 3) (Sharma, Wu & Dalal 2005, kL = kC = kH = 1).

    The formulas are the paper's, with the angles in radians and its four cosines of the
    mean hue h̄ in T = 1 − 0.17 cos(h̄ − 30°) + 0.24 cos 2h̄ + 0.32 cos(3h̄ + 6°) − 0.20
    cos(4h̄ − 63°) taken from cos h̄ and sin h̄ by the angle-addition formulas, and the
    chromas as √(a² + b²): a fit computes this for every pixel, and the four cosines, the
    degree conversions and ``np.hypot`` were most of its time (18-20 ms → 12.6 ms at 51 000
    pixels, 2026-12-04; the same values to about 2e-13 absolute over 200 000 random pairs and
    the edge cases of hue wrap-around and achromatic colours, the published pairs to 5e-5)."""
    l1, a1, b1 = np.moveaxis(np.asarray(lab1, dtype=np.float64), -1, 0)
    l2, a2, b2 = np.moveaxis(np.asarray(lab2, dtype=np.float64), -1, 0)
    # √(a² + b²) rather than np.hypot, which guards an overflow that L*a*b* values (|a|, |b|
    # below a few hundred) cannot reach, at several times the cost
    c_mean7 = _seventh((np.sqrt(a1 * a1 + b1 * b1) + np.sqrt(a2 * a2 + b2 * b2)) / 2)
    g = 0.5 * (1 - np.sqrt(c_mean7 / (c_mean7 + _POW25_7)))
    a1p, a2p = (1 + g) * a1, (1 + g) * a2
    c1p, c2p = np.sqrt(a1p * a1p + b1 * b1), np.sqrt(a2p * a2p + b2 * b2)
    two_pi = 2 * math.pi
    h1p, h2p = np.arctan2(b1, a1p), np.arctan2(b2, a2p)  # in (−π, π], taken to [0, 2π)
    h1p = np.where(h1p < 0, h1p + two_pi, h1p)
    h2p = np.where(h2p < 0, h2p + two_pi, h2p)
    chroma = c1p * c2p
    dh = h2p - h1p
    dh = np.where(chroma == 0, 0.0, np.where(dh > math.pi, dh - two_pi, np.where(dh < -math.pi, dh + two_pi, dh)))
    d_l, d_c = l2 - l1, c2p - c1p
    d_h = 2 * np.sqrt(chroma) * np.sin(dh / 2)
    l_mean, cp_mean = (l1 + l2) / 2, (c1p + c2p) / 2
    h_sum = h1p + h2p
    h_mean = np.where(
        chroma == 0,
        h_sum,
        np.where(
            np.abs(h1p - h2p) <= math.pi,
            h_sum / 2,
            np.where(h_sum < two_pi, (h_sum + two_pi) / 2, (h_sum - two_pi) / 2),
        ),
    )
    cos1, sin1 = np.cos(h_mean), np.sin(h_mean)
    cos2, sin2 = 2 * cos1 * cos1 - 1, 2 * sin1 * cos1
    cos3, sin3 = cos1 * cos2 - sin1 * sin2, sin1 * cos2 + cos1 * sin2
    cos4, sin4 = 2 * cos2 * cos2 - 1, 2 * sin2 * cos2
    (c30, s30), (c6, s6), (c63, s63) = _T_PHASES[30], _T_PHASES[6], _T_PHASES[63]
    t = (
        1
        - 0.17 * (cos1 * c30 + sin1 * s30)  # cos(h̄ − 30°)
        + 0.24 * cos2
        + 0.32 * (cos3 * c6 - sin3 * s6)  # cos(3h̄ + 6°)
        - 0.20 * (cos4 * c63 + sin4 * s63)  # cos(4h̄ − 63°)
    )
    d_theta = math.radians(30) * np.exp(-(((np.degrees(h_mean) - 275) / 25) ** 2))
    cp_mean7 = _seventh(cp_mean)
    r_c = 2 * np.sqrt(cp_mean7 / (cp_mean7 + _POW25_7))
    l_offset = (l_mean - 50) ** 2
    s_l = 1 + 0.015 * l_offset / np.sqrt(20 + l_offset)
    s_c, s_h = 1 + 0.045 * cp_mean, 1 + 0.015 * cp_mean * t
    r_t = -np.sin(2 * d_theta) * r_c
    return np.sqrt((d_l / s_l) ** 2 + (d_c / s_c) ** 2 + (d_h / s_h) ** 2 + r_t * (d_c / s_c) * (d_h / s_h))


def display_scale(reference: np.ndarray) -> float:
    """The exposure `delta_e_2000` divides by: the larger of 1 and the 99th percentile of
    ``reference`` (NumPy's linear interpolation), 1 when it is empty. The percentile is
    taken only when more than 1 % of the values exceed 1: else the order statistic above
    the interpolated position is at most 1, and so is the percentile (a count instead of a
    partial sort, 0.05 against 1.7 ms at 256²)."""
    values = np.asarray(reference, dtype=np.float64).ravel()
    if values.size == 0:
        return 1.0
    upper = math.ceil(0.99 * (values.size - 1))  # the higher of the two ranks interpolated
    if np.count_nonzero(values > 1.0) <= values.size - 1 - upper:
        return 1.0
    return max(1.0, float(np.percentile(values, 99)))


def delta_e_2000(rgb: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Per-pixel ΔE2000 between ``rgb`` and ``reference`` (shapes (..., 3), linear; see the
    module docstring for the exposure)."""
    rgb = np.asarray(rgb, dtype=np.float64)
    reference = np.asarray(reference, dtype=np.float64)
    scale = display_scale(reference)
    return ciede2000(linear_to_lab(np.clip(rgb / scale, 0.0, 1.0)), linear_to_lab(np.clip(reference / scale, 0.0, 1.0)))

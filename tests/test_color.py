"""Colour: the sRGB curve, CIE L*a*b* and CIEDE2000 (strauss_fit.color), checked against colour-science."""

import colour
import numpy as np
import pytest

from strauss_fit.color import delta_e_2000


def test_white_against_black_is_100_and_an_image_against_itself_is_0():
    # L* = 100 against L* = 0 with a* = b* = 0: mean L' = 50, so S_L = 1 and ΔE00 = ΔL' = 100
    white, black = np.ones((1, 3)), np.zeros((1, 3))
    assert float(delta_e_2000(black, white)[0]) == pytest.approx(100.0, abs=1e-6)
    rng = np.random.default_rng(0)
    image = rng.random((50, 3))
    assert np.all(delta_e_2000(image, image) == 0)


def test_matches_colour_sciences_full_conversion_chain():
    # the module applies sRGB's matrix itself instead of colour.RGB_to_XYZ: same numbers
    rng = np.random.default_rng(1)
    reference = rng.random((400, 3)) * 1.5
    image = reference + 0.05 * rng.normal(size=reference.shape)
    space = colour.RGB_COLOURSPACES["sRGB"]
    scale = max(1.0, float(np.percentile(reference, 99)))

    def lab(values):
        return colour.XYZ_to_Lab(colour.RGB_to_XYZ(np.clip(values / scale, 0, 1), space), space.whitepoint)

    expected = colour.delta_E(lab(image), lab(reference), method="CIE 2000")
    np.testing.assert_allclose(delta_e_2000(image, reference), expected, rtol=1e-10, atol=1e-10)


def test_hdr_images_are_compared_at_the_references_exposure():
    # both images scaled by the same factor above 1: the exposure follows the reference's
    # 99th percentile, so the difference is unchanged
    rng = np.random.default_rng(2)
    reference = rng.random((300, 3)) * 2.0
    image = reference * 0.97
    np.testing.assert_allclose(delta_e_2000(4 * image, 4 * reference), delta_e_2000(image, reference), rtol=1e-9)


def test_the_srgb_curve_and_lab_agree_with_colour_science():
    from strauss_fit.color import linear_to_lab, srgb_decode, srgb_encode

    values = np.r_[np.linspace(0.0, 1.0, 2001), 0.0031308, 0.04045, 1e-9]
    np.testing.assert_allclose(srgb_decode(values), colour.cctf_decoding(values, function="sRGB"), rtol=1e-12)
    np.testing.assert_allclose(srgb_encode(values), colour.cctf_encoding(values, function="sRGB"), rtol=1e-12)
    rng = np.random.default_rng(5)
    rgb = rng.random((500, 3))
    space = colour.RGB_COLOURSPACES["sRGB"]
    expected = colour.XYZ_to_Lab(colour.RGB_to_XYZ(rgb, space), space.whitepoint)
    np.testing.assert_allclose(linear_to_lab(rgb), expected, rtol=1e-12, atol=1e-10)


def test_ciede2000_matches_the_published_test_pairs():
    # Sharma, Wu & Dalal (2005), Table 1: pairs 1, 7, 17, 19, 25 and 34 (the last of 34 pairs)
    from strauss_fit.color import ciede2000

    pairs = [
        ((50.0, 2.6772, -79.7751), (50.0, 0.0, -82.7485), 2.0425),
        ((50.0, 0.0, 0.0), (50.0, -1.0, 2.0), 2.3669),
        ((50.0, 2.5, 0.0), (73.0, 25.0, -18.0), 27.1492),
        ((50.0, 2.5, 0.0), (50.0, 3.1736, 0.5854), 1.0),
        ((60.2574, -34.0099, 36.2677), (60.4626, -34.1751, 39.4387), 1.2644),
        ((2.0776, 0.0795, -1.1350), (0.9033, -0.0636, -0.5514), 0.9082),
    ]
    for one, two, expected in pairs:
        assert float(ciede2000(np.array(one), np.array(two))) == pytest.approx(expected, abs=5e-5)


@pytest.mark.parametrize("size", [1, 2, 99, 100, 101, 1000, 1001])
def test_the_display_scale_is_the_99th_percentile_or_1_with_or_without_the_shortcut(size):
    """`display_scale` skips the percentile when few values exceed 1: for every count of
    values above 1 around the cut, and values exactly at 1, it equals max(1, percentile)."""
    from strauss_fit.color import display_scale

    rng = np.random.default_rng(size)
    for above in sorted({0, 1, size // 100, size // 100 + 1, size // 100 + 2, size // 2, size}):
        above = min(above, size)
        for high in (1.0 + 1e-12, 1.5, 40.0):
            values = np.concatenate([rng.uniform(0.0, 1.0, size - above), np.full(above, high)])
            if above < size:
                values[0] = 1.0  # a value exactly at 1 among those not above it
            rng.shuffle(values)
            expected = max(1.0, float(np.percentile(values, 99)))
            assert display_scale(values.reshape(-1, 1)) == expected
    assert display_scale(np.zeros((0, 3))) == 1.0

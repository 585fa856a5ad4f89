"""CIEDE2000 between linear RGB images (strauss_fit.colour_difference)."""

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

"""Images: read by their real format, damaged files refused, encoded in memory."""

import shutil

import numpy as np
import pytest

from strauss_fit.errors import ImageError
from strauss_fit.io.images import encode_image, read_image, write_image


def test_a_truncated_jpeg_is_refused_not_filled_with_grey(tmp_path):
    path = tmp_path / "photo.jpg"
    write_image(path, np.random.default_rng(0).random((64, 64, 3)))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ImageError, match="Premature end of JPEG file") as info:
        read_image(path)
    assert "\n" not in str(info.value) and str(path) in str(info.value)


@pytest.mark.parametrize("suffix", [".png", ".exr", ".tif"])
def test_other_truncated_images_are_refused(tmp_path, suffix):
    path = tmp_path / f"image{suffix}"
    write_image(path, np.random.default_rng(1).random((48, 48, 3)))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(ImageError, match="cannot read image"):
        read_image(path)


def test_a_png_renamed_exr_is_decoded_as_the_png_it_is(tmp_path):
    png = tmp_path / "real.png"
    write_image(png, np.full((8, 8, 3), 0.25))
    renamed = tmp_path / "fake.exr"
    shutil.copy(png, renamed)
    as_png, as_exr = read_image(png), read_image(renamed)
    assert as_exr.encoding == "srgb"
    np.testing.assert_array_equal(as_exr.pixels, as_png.pixels)
    np.testing.assert_array_equal(as_exr.clipped, as_png.clipped)


@pytest.mark.parametrize("suffix", [".png", ".jpg", ".exr", ".tif", ".hdr", ".bmp", ".tga"])
def test_encoding_in_memory_gives_the_file_write_image_writes(tmp_path, suffix):
    image = np.random.default_rng(2).random((16, 20, 3))
    path = write_image(tmp_path / f"x{suffix}", image)
    assert path.read_bytes() == encode_image(image, path)
    assert read_image(path).pixels.shape == (16, 20, 3)
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no temporary left

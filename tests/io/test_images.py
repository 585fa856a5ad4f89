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


@pytest.mark.parametrize(
    "suffix,keep,message",
    [
        (".exr", 0, "the file is empty"),
        (".exr", 60, "not a readable .exr file (damaged or truncated?)"),
        (".jpg", 0, "the file is empty"),
    ],
)
def test_an_empty_or_cut_short_file_is_not_blamed_on_its_format(tmp_path, suffix, keep, message):
    """OpenImageIO says it "could not find a format reader" for an empty or cut-short file of
    a format it reads (hostile-user pass): the message says what is wrong with the file."""
    path = tmp_path / f"image{suffix}"
    write_image(path, np.random.default_rng(1).random((48, 48, 3)))
    path.write_bytes(path.read_bytes()[:keep])
    with pytest.raises(ImageError) as info:
        read_image(path)
    assert str(info.value) == f"cannot read image {path}: {message}"


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


@pytest.mark.parametrize("suffix, alpha", [(".png", 0), (".png", 128), (".tif", 0)])
def test_alpha_is_ignored_the_colour_channels_are_read_as_stored(tmp_path, suffix, alpha):
    # before: OpenImageIO premultiplied a PNG's unassociated alpha, so a PNG with alpha 0
    # everywhere read as black ("black on every usable sphere pixel")
    import OpenImageIO as oiio

    path = tmp_path / f"rgba{suffix}"
    pixels = np.zeros((6, 5, 4), np.uint8)
    pixels[..., 0], pixels[..., 1], pixels[..., 2], pixels[..., 3] = 200, 100, 50, alpha
    spec = oiio.ImageSpec(5, 6, 4, oiio.UINT8)
    spec.attribute("oiio:UnassociatedAlpha", 1)  # store the values as given (as an editor does)
    output = oiio.ImageOutput.create(str(path))
    assert output.open(str(path), spec) and output.write_image(pixels)
    output.close()
    image = read_image(path, encoding="linear")
    np.testing.assert_allclose(image.pixels[0, 0], np.array([200, 100, 50]) / 255, atol=1e-6)
    assert image.pixels.shape == (6, 5, 3)


def test_inputs_that_are_not_regular_files_are_named(tmp_path):
    import os
    import socket

    from strauss_fit.errors import StraussFitError
    from strauss_fit.io.files import check_input_file

    regular = tmp_path / "a.exr"
    regular.write_bytes(b"x")
    assert check_input_file(regular) == regular
    (tmp_path / "link.exr").symlink_to(regular)
    assert check_input_file(tmp_path / "link.exr") == tmp_path / "link.exr"
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    (tmp_path / "broken").symlink_to(tmp_path / "gone")
    with socket.socket(socket.AF_UNIX) as server:
        server.bind(str(tmp_path / "sock"))
        cases = {
            "fifo": "image {p} is not a regular file (a FIFO)",
            "sock": "image {p} is not a regular file (a socket)",
            "loop": "image {p} is a symbolic link loop",
            "broken": f"image {{p}} is a broken symbolic link (to {tmp_path / 'gone'})",
            "missing": "image not found: {p}",
            ".": "image path is a directory: {p}",
        }
        for name, message in cases.items():
            path = tmp_path / name
            with pytest.raises(ImageError) as info:
                check_input_file(path, "image", ImageError)
            assert str(info.value) == message.format(p=path)
    assert issubclass(ImageError, StraussFitError)
    with pytest.raises(ImageError, match="not a regular file"):
        read_image("/dev/zero")  # a device would stream for ever

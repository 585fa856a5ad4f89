"""The registries that replace string switches (issue 28): the losses, the output writers and
the command line's shared options. Every place that accepts or lists a name reads it from
its registry, so each test here checks that a place agrees with the registry: what it
accepts, what it refuses, what its help lists, and that the plain data the command line
reads (without NumPy or JAX) agrees with the numerical side keyed by the same names."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import types

import numpy as np
import pytest

from strauss_fit.errors import StraussFitError
from strauss_fit.fitting import losses
from strauss_fit.fitting.options import MISMATCH_LOSS, FitOptions
from strauss_fit.io import table_formats
from strauss_fit_cli.main import build_parser

#: Names no registry holds: near misses of real ones, and no name at all.
NOT_NAMES = ("", "Huber", "LINEAR", "l2", "huber ", "least-squares", "autos")


def _subcommand(name: str) -> argparse.ArgumentParser:
    parser = build_parser()
    actions = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return actions.choices[name]


def _option(parser: argparse.ArgumentParser, flag: str) -> argparse.Action:
    return next(action for action in parser._actions if flag in action.option_strings)


def _help_of(parser: argparse.ArgumentParser, flag: str) -> str:
    """The help text of option ``flag`` as ``--help`` prints it (its lines joined)."""
    text = parser.format_help()
    start = text.index(f"  {flag}")
    following = re.search(r"\n  -", text[start + 2 :])
    block = text[start : start + 2 + following.start()] if following else text[start:]
    return " ".join(block.split())


# --- losses ----------------------------------------------------------------------------------


def _fit_args(*more: str) -> list[str]:
    return ["fit", "t.exr", "--scene", "s.toml", "-o", "r.json", *more]


@pytest.mark.parametrize("name", losses.LOSS_CHOICES)
def test_every_loss_of_the_registry_is_accepted_by_the_command_line_and_the_fit_options(name):
    assert build_parser().parse_args(_fit_args("--loss", name)).loss == name
    FitOptions(loss=name).validate()


@pytest.mark.parametrize("name", NOT_NAMES)
def test_a_name_outside_the_registry_is_refused_by_both(name, capsys):
    with pytest.raises(SystemExit) as refused:
        build_parser().parse_args(_fit_args("--loss", name))
    assert refused.value.code == 2
    assert "invalid choice" in capsys.readouterr().err
    with pytest.raises(StraussFitError, match="unknown loss"):
        FitOptions(loss=name).validate()


def test_the_loss_option_lists_exactly_the_registry_with_its_descriptions():
    parser = _subcommand("fit")
    action = _option(parser, "--loss")
    assert tuple(action.choices) == losses.LOSS_CHOICES == ("auto", *losses.LOSS_REGISTRY)
    assert action.default == losses.AUTO == FitOptions().loss
    assert f"--loss {{{','.join(losses.LOSS_CHOICES)}}}" in parser.format_usage()
    text = _help_of(parser, "--loss")
    for name, loss in losses.LOSS_REGISTRY.items():
        assert f"{name}, {' '.join(loss.description.split())}" in text
    assert f"auto, the default: linear, then {MISMATCH_LOSS}" in text


def test_the_derived_loss_lists_are_the_registrys():
    assert losses.LOSSES == ("linear", "perceptual", "huber", "cauchy")
    assert losses.ROBUST_LOSSES == ("huber", "cauchy")
    assert losses.FOLDED_LOSSES == ("linear", "huber", "cauchy")
    # the folded losses' codes are their indices, 0, 1, 2, ...
    assert [losses.LOSS_REGISTRY[name].code for name in losses.FOLDED_LOSSES] == list(range(len(losses.FOLDED_LOSSES)))
    assert all(name == loss.name for name, loss in losses.LOSS_REGISTRY.items())
    assert losses.LEAST_SQUARES in losses.FOLDED_LOSSES and losses.LOSS_REGISTRY[losses.LEAST_SQUARES].code == 0
    assert MISMATCH_LOSS in losses.ROBUST_LOSSES  # the fit's noise picks its weights
    assert losses.loss_named("huber") is losses.LOSS_REGISTRY["huber"]
    with pytest.raises(StraussFitError, match="unknown loss 'l2'; expected one of linear, perceptual, huber, cauchy"):
        losses.loss_named("l2")


def test_the_loss_names_are_plain_data_the_command_line_reads_without_numpy_or_jax():
    code = (
        "import sys\n"
        "import strauss_fit.fitting.losses\n"
        "from strauss_fit_cli.main import build_parser\n"
        "build_parser()\n"
        "print(sorted(m for m in ('numpy', 'jax', 'scipy') if m in sys.modules))\n"
    )
    finished = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert finished.stdout.strip() == "[]"


def test_the_numerical_losses_are_keyed_by_the_registrys_names():
    from strauss_fit.fitting import problem

    assert set(problem.LOSS_RESIDUALS) == set(losses.LOSS_REGISTRY)
    assert set(problem.ROBUST_PSI) == set(losses.ROBUST_LOSSES)
    assert set(problem.LOSS_FIELDS) <= set(losses.LOSSES) - set(losses.ROBUST_LOSSES)
    # a kernel form selects among least squares and the robust losses' ψ (_folded_residual)
    assert set(losses.FOLDED_LOSSES) <= {losses.LEAST_SQUARES, *losses.ROBUST_LOSSES}
    assert not set(problem.LOSS_FIELDS) & set(losses.FOLDED_LOSSES)  # a folded loss needs no fields of its own
    # the names other modules import from problem are the registry's
    assert (problem.LOSSES, problem.ROBUST_LOSSES, problem.FOLDED_LOSSES) == (
        losses.LOSSES,
        losses.ROBUST_LOSSES,
        losses.FOLDED_LOSSES,
    )
    assert problem.LOSS_BY_CODE == "linear, huber or cauchy, by loss_code"  # a static field: a compiled program's key


def _residual_problem(loss: str, rng: np.random.Generator, **fields) -> types.SimpleNamespace:
    """What :func:`strauss_fit.fitting.problem.loss_residual` reads of a problem."""
    shape = (40, 3)
    values = dict(
        loss=loss,
        target=rng.uniform(0.05, 0.9, shape),
        weights=rng.uniform(0.5, 2.0, shape),
        count=None,
        residual_scale=np.asarray(0.01 * np.sqrt(40 * 3)),
        loss_offset=None,
        loss_norm=None,
        loss_code=None,
    )
    values.update(fields)
    return types.SimpleNamespace(**values)


@pytest.mark.parametrize("name", losses.FOLDED_LOSSES)
def test_a_kernel_forms_residual_is_each_folded_losss_own(name, x64):
    """The loss held as data (its code) gives the values its own residual function gives, to
    the last bit or two: the folded residual runs its loss's branch as one compiled
    computation (``lax.switch``), whose fused operations may round differently from the
    same operations run one by one."""
    from strauss_fit.fitting.problem import LOSS_BY_CODE, LOSS_RESIDUALS, loss_residual

    rng = np.random.default_rng(7)
    own = _residual_problem(name, rng)
    model = own.target + rng.normal(0.0, 0.05, own.target.shape)  # beyond Huber's and Cauchy's knees
    folded = _residual_problem(
        LOSS_BY_CODE, np.random.default_rng(7), loss_code=np.asarray(losses.LOSS_REGISTRY[name].code, dtype=np.int32)
    )
    expected = np.asarray(LOSS_RESIDUALS[name](own, model, own.target))
    np.testing.assert_array_equal(np.asarray(loss_residual(own, model)), expected)
    np.testing.assert_allclose(np.asarray(loss_residual(folded, model)), expected, rtol=1e-15, atol=0)
    if name != losses.LEAST_SQUARES:
        assert not np.allclose(expected, model - own.target)  # the loss does transform these


def test_the_losses_values_are_the_documented_ones(x64):
    """Each loss's residual, computed from its definition (docs/mismatch.md#the-loss)."""
    from strauss_fit.fitting.problem import CAUCHY_C, HUBER_K, LOSS_RESIDUALS

    rng = np.random.default_rng(3)
    problem = _residual_problem("huber", rng, loss_offset=np.asarray(1e-3), loss_norm=np.asarray(0.7))
    model = problem.target + rng.normal(0.0, 0.05, problem.target.shape)
    reference = 0.01
    z = (model - problem.target) * problem.weights / reference
    huber = np.where(np.abs(z) <= HUBER_K, z**2 / 2, HUBER_K * np.abs(z) - HUBER_K**2 / 2)
    cauchy = CAUCHY_C**2 / 2 * np.log1p((z / CAUCHY_C) ** 2)
    perceptual = (np.cbrt(model + 1e-3) - np.cbrt(problem.target + 1e-3)) / 0.7
    found = {name: np.asarray(function(problem, model, problem.target)) for name, function in LOSS_RESIDUALS.items()}
    np.testing.assert_allclose(found["linear"], model - problem.target, rtol=1e-15)
    np.testing.assert_allclose(found["perceptual"], perceptual, rtol=1e-12)
    np.testing.assert_allclose((found["huber"] / reference) ** 2 / 2, huber, rtol=1e-12)
    np.testing.assert_allclose((found["cauchy"] / reference) ** 2 / 2, cauchy, rtol=1e-12)
    assert np.all(np.sign(found["huber"]) == np.sign(z)) and np.all(np.sign(found["cauchy"]) == np.sign(z))


# --- output writers --------------------------------------------------------------------------


@pytest.mark.parametrize("suffix", list(table_formats.IMAGE_FORMATS))
def test_every_image_format_round_trips(suffix, tmp_path):
    """An image written with a registered extension reads back as written: float formats as
    linear float32 (.hdr's RGBE to its 8-bit mantissas), 8-bit formats as their sRGB codes
    (a JPEG to its compression)."""
    from strauss_fit.io.images import IMAGE_WRITERS, default_encoding, read_image, write_image

    image_format = table_formats.IMAGE_FORMATS[suffix]
    assert suffix in IMAGE_WRITERS and default_encoding(f"x{suffix.upper()}") == image_format.encoding
    # smooth, so that a JPEG's compression stays small; every value distinct
    rows, columns = np.meshgrid(np.linspace(0.2, 0.8, 6), np.linspace(0.1, 0.9, 7), indexing="ij")
    image = np.stack([rows, columns, 0.5 * (rows + columns)], axis=-1) + np.arange(6 * 7 * 3).reshape(6, 7, 3) * 1e-4
    path = write_image(tmp_path / f"image{suffix}", image)
    loaded = read_image(path)
    assert loaded.encoding == image_format.encoding
    assert loaded.bits == (8 if image_format.ldr else None)
    if image_format.ldr:
        from strauss_fit.color import srgb_encode

        codes = np.round(srgb_encode(image) * 255.0)
        if suffix in (".jpg", ".jpeg"):  # lossy (and its colours subsampled): on average
            np.testing.assert_allclose(loaded.pixels.mean(axis=(0, 1)), image.mean(axis=(0, 1)), atol=0.03)
        else:
            np.testing.assert_array_equal(np.round(srgb_encode(loaded.pixels) * 255.0), codes)
    elif suffix == ".hdr":
        # one 8-bit mantissa per channel under the pixel's largest channel's exponent
        assert np.all(np.abs(loaded.pixels - image) <= image.max(axis=-1, keepdims=True) / 128)
    else:
        np.testing.assert_array_equal(loaded.pixels, image.astype(np.float32))


def test_the_image_formats_split_into_the_hdr_and_ldr_extensions():
    from strauss_fit.io import images

    assert images.HDR_EXTENSIONS == (".exr", ".hdr", ".tif", ".tiff", ".pfm")
    assert images.LDR_EXTENSIONS == (".png", ".jpg", ".jpeg", ".bmp", ".tga")
    assert set(images.IMAGE_WRITERS) == set(table_formats.IMAGE_FORMATS)
    assert all(suffix == suffix.lower() and suffix.startswith(".") for suffix in table_formats.IMAGE_FORMATS)
    assert all(suffix == f.suffix for suffix, f in table_formats.IMAGE_FORMATS.items())


@pytest.mark.parametrize("name", ["x.xyz", "x"])
def test_an_image_output_no_writer_knows_lists_the_formats(name, tmp_path):
    from strauss_fit.io.images import check_image_output, encode_image

    expected = f"expected one of {', '.join(table_formats.IMAGE_FORMATS)}"
    with pytest.raises(StraussFitError, match="no image writer for") as refused:
        check_image_output(tmp_path / name)
    assert str(refused.value).endswith(expected)
    with pytest.raises(StraussFitError, match="no image writer for") as refused:
        encode_image(np.zeros((2, 2, 3)), tmp_path / name)
    assert str(refused.value).endswith(expected)


def test_the_render_help_lists_the_image_formats():
    parser = _subcommand("render")
    text = " ".join(parser.format_help().split())
    for suffixes, how in (
        (table_formats.HDR_EXTENSIONS, "are written as linear float"),
        (table_formats.LDR_EXTENSIONS, "are sRGB-encoded and clipped to 8 bits"),
    ):
        assert f"{table_formats.describe_suffixes(suffixes)} {how}" in text
    assert f"output image ({table_formats.describe_suffixes(table_formats.IMAGE_FORMATS)})" in _help_of(parser, "-o")


@pytest.mark.parametrize("direction", table_formats.DIRECTIONS)
def test_every_material_table_format_is_written_and_listed(direction, tmp_path):
    """The conversions' outputs (:data:`~strauss_fit.io.table_formats.OUTPUT_FORMATS`): each
    extension has its writer, names its format, and the help lists exactly the extensions."""
    from strauss_fit.io import material_tables

    suffixes = table_formats.output_suffixes(direction)
    assert set(material_tables.OUTPUT_WRITERS) == {name for name, _ in table_formats.OUTPUT_FORMATS.values()}
    for suffix in suffixes:
        name = material_tables.output_format(tmp_path / f"out{suffix}", direction)
        assert name == table_formats.OUTPUT_FORMATS[suffix][0]
    with pytest.raises(StraussFitError, match=f"expected {re.escape(table_formats.describe_suffixes(suffixes))}$"):
        material_tables.output_format(tmp_path / "out.xyz", direction)
    help_text = _help_of(_subcommand(direction), "-o")
    assert f"results: {table_formats.describe_suffixes(suffixes)} (by extension)" in help_text


# --- the command line's shared options -------------------------------------------------------

#: The commands that fit one target by least squares (``sample`` when it fits first).
FITTING_COMMANDS = ("fit", "sample")


def test_the_search_options_choices_are_the_fit_options(x64):
    from strauss_fit.fitting import options, solvers

    parser = _subcommand("fit")
    for flag, names in (
        ("--search", options.SEARCHES),
        ("--edge-pixels", options.EDGE_PIXELS),
        ("--loss", losses.LOSS_CHOICES),
        ("--solver", options.SOLVERS),
    ):
        action = _option(parser, flag)
        assert tuple(action.choices) == names
        assert f"{flag} {{{','.join(names)}}}" in parser.format_usage()
    assert options.SOLVERS == solvers.SOLVERS  # the plain names the command line lists are the solvers'
    for name in options.SEARCHES:
        assert build_parser().parse_args(_fit_args("--search", name)).search == name
        FitOptions(search=name).validate()


@pytest.mark.parametrize("flag", ["--solver", "--starts", "--free", "--fix", "--fit-lights", "--mode", "--table-size"])
def test_a_fitting_option_is_the_same_option_in_every_command_that_fits(flag):
    """One definition (:mod:`strauss_fit_cli._options`): the same choices, default, type and
    metavar in ``fit`` and ``sample``."""
    found = [_option(_subcommand(command), flag) for command in FITTING_COMMANDS]
    described = {
        (tuple(a.choices or ()), repr(a.default), getattr(a.type, "__name__", None), a.metavar, type(a)) for a in found
    }
    assert len(described) == 1


def test_every_image_encoding_option_offers_the_registered_encodings():
    from strauss_fit.io.table_formats import IMAGE_ENCODINGS

    for command in ("fit", "sample", "compare", "report"):
        assert tuple(_option(_subcommand(command), "--encoding").choices) == IMAGE_ENCODINGS
    # a mirror ball's images are decoded as named: no automatic choice
    assert tuple(_option(_subcommand("lights"), "--encoding").choices) == ("linear", "srgb")


def test_every_command_has_its_output_and_force_options():
    parser = build_parser()
    actions = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name, command in actions.choices.items():
        output = _option(command, "-o")
        assert output.required and output.option_strings == ["-o", "--output"], name
        assert _option(command, "--force").default is False, name

"""``strauss-fit compare``: several reflectance models fitted to the same target or capture,
and whether Strauss is distinguishable from the best (see docs/commands/compare.md).

A thin shell over `strauss_fit.fitting.compare.fit_models` and
`strauss_fit.reporting.compare_figure.comparison_figure`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ._options import (
    add_capture_inputs,
    add_force_option,
    add_image_inputs,
    add_noise_options,
    add_output_option,
    add_quiet_option,
)
from .common import escape, positive_int, progress_printer


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "compare",
        help="fit several reflectance models to one target or capture: is Strauss distinguishable from the best?",
        description="Fit each reflectance model (default: every one the fitter knows) to the same target and "
        "scene, or to the same capture, and compare them: relative RMS, mean CIEDE2000, χ²/dof when the noise is "
        "known, AIC and BIC, and with --holdout the error on held-out images. Says whether Strauss's fit is "
        "distinguishable from the best model's (ΔBIC > 10, and a higher held-out error) and whether the "
        "difference is visible (CIEDE2000 between the two fits ≥ 1). Writes COMPARE.json and a PNG beside it "
        "(one image: the target, each model's prediction and residual). See docs/commands/compare.md.",
    )
    add_image_inputs(
        parser,
        target=dict(nargs="?", help="one reference image (with --scene)"),
        scene="the scene TARGET was taken in",
        encoding="how the images' values are encoded (default: TARGET by its file type; a capture as it states)",
    )
    add_capture_inputs(
        parser,
        capture="a capture instead of TARGET: a manifest, a folder, or image files with --lights (docs/captures.md)",
        lights="--capture images' lights, by order",
    )
    parser.add_argument(
        "--models",
        metavar="LIST",
        help="comma-separated models to fit (default: every model the fitter knows, e.g. "
        "strauss,lambert,phong,blinn-phong)",
    )
    add_output_option(parser, metavar="COMPARE.json", help="the comparison (JSON)")
    add_noise_options(
        parser,
        reference=False,  # only the noise: compare takes no --reference-noise
        metavar="SIGMA|R,G,B",
        help="the noise σ (linear), when known: χ²/dof and AIC/BIC from it (default: TARGET's sidecar, else "
        "unknown: σ profiled out)",
    )
    parser.add_argument(
        "--fit-exposure",
        action="store_true",
        help="also fit the exposure: one global scale for TARGET; one per image for a capture",
    )
    parser.add_argument(
        "--holdout",
        metavar="K|LIST",
        help="capture: leave out every K-th image (or the 1-based images in LIST), fit the rest, predict them; "
        "the best model is then the one with the lowest held-out relative RMS",
    )
    parser.add_argument(
        "--image",
        type=positive_int,
        default=1,
        metavar="K",
        help="the image the figure shows (1-based; default 1)",
    )
    add_force_option(parser)
    add_quiet_option(parser, "print only the table and the verdict")
    parser.set_defaults(run=run)


def figure_path(output: str | Path) -> Path:
    """The figure written beside COMPARE.json: the same name, ``.png``."""
    return Path(output).with_suffix(".png")


def _target_noise(args: argparse.Namespace, samples, target):
    """σ per value of TARGET (given, else its sidecar's) and what it came from; (None, note)
    when unknown."""
    from strauss_fit.stats.noise import describe_noise, read_sidecar, unusable_sidecar

    from .fit_cmd import parse_noise

    given = parse_noise(args.noise)
    sidecar = None if given is not None else read_sidecar(target.path)
    if given is None and sidecar is None:
        problem = unusable_sidecar(target.path, None)  # one that is there but not readable
        return None, f"unknown (no --noise; {problem})" if problem else "unknown (no --noise, no sidecar)"
    model = describe_noise(
        target.pixels, target.usable, encoding=target.encoding, path=target.path, given=given, sidecar=sidecar or {}
    )
    if model.source not in ("given", "sensor"):
        return None, f"unknown ({model.sidecar_problem or 'the sidecar states no noise'})"
    sigma = model.sigma_at(samples.values)  # at the observed level: the same σ for every model
    if not (sigma[samples.usable] > 0).all():
        return None, "unknown (the sidecar's noise is zero: a noise-free image)"
    return sigma, f"{model.source}: {'; '.join(model.notes)}"


def run(args: argparse.Namespace) -> int:
    from strauss_fit.errors import StraussFitError
    from strauss_fit.fitting.compare import check_models, fit_models, format_comparison_table
    from strauss_fit.io.files import Outputs

    models = check_models(args.models)
    if not args.output.strip():
        raise StraussFitError("-o is empty: give COMPARE.json")
    if not Path(args.output).name:  # '.', '/': no file name to put the figure beside
        raise StraussFitError(f"-o {args.output} is a folder: give COMPARE.json")
    png = figure_path(args.output)
    log = progress_printer(args.quiet, "... ")
    if args.capture:
        if args.target:
            raise StraussFitError("give either TARGET (with --scene) or --capture, not both")
        if args.scene is not None:
            raise StraussFitError("a capture states its own lights and camera: --scene is for a single TARGET")
        samples, inputs, exposure, noise, noise_source = _capture_samples(args, png, log)
    else:
        if not args.target:
            raise StraussFitError("give TARGET (with --scene) or --capture")
        if args.scene is None:
            raise StraussFitError("TARGET needs its scene (--scene SCENE.toml)")
        if args.lights is not None:
            raise StraussFitError("--lights is for --capture images")
        if args.holdout is not None:
            raise StraussFitError("--holdout needs a capture of several images (--capture)")
        samples, inputs, exposure, noise, noise_source = _target_samples(args, png)
    if args.image > samples.count:
        raise StraussFitError(f"--image {args.image}: there are {samples.count} images, numbered from 1")
    comparison = fit_models(samples, models, exposure=exposure, holdout=args.holdout, noise=noise, progress=log)
    result = comparison.result
    result["noise"]["source"] = noise_source
    result["inputs"] = inputs
    result["figure"] = {"file": png.name, "image": args.image}

    from strauss_fit.fitting.capture_result import holdout_indices
    from strauss_fit.reporting.compare_figure import comparison_figure

    held = holdout_indices(args.holdout, samples.count) if args.holdout is not None else []
    figure = comparison_figure(samples, comparison.predictions, args.image - 1, held_out=held, order=models)
    with Outputs(force=args.force) as out:
        out.add_json(args.output, result)
        out.add_bytes(png, figure)
        written = out.commit(final=True)
    print(escape(format_comparison_table(result)))
    print(escape(f"wrote {', '.join(str(p) for p in written)}", newlines=True))
    return 1 if result["failed"] else 0


def _check_outputs(args: argparse.Namespace, png: Path, inputs: dict) -> None:
    from strauss_fit.io.files import check_distinct, check_writable

    check_distinct({"-o": args.output, "the figure beside -o": png}, inputs)
    check_writable(args.output, args.force)
    check_writable(png, args.force)


def _capture_samples(args: argparse.Namespace, png: Path, log):
    from strauss_fit.capture import capture_inputs, load_samples, open_capture

    from .fit_capture import description_files
    from .fit_cmd import parse_noise

    encoding = None if args.encoding == "auto" else args.encoding
    capture = open_capture(args.capture, args.lights, args.mask, encoding)
    named = {f"--capture image {i + 1}": image.path for i, image in enumerate(capture.images)}
    named.update({"--capture": args.capture[0], "--lights": args.lights, "--mask": capture.mask})
    named.update(description_files(capture))
    _check_outputs(args, png, named)
    given = parse_noise(args.noise)
    if given is not None:  # σ² and 1/σ² within float64's range, as for TARGET's noise
        from strauss_fit.stats.noise import check_noise_level

        check_noise_level(given, "--noise")
    log(f"reading {len(capture.images)} images")
    samples = load_samples(capture)
    exposure = "per-image" if args.fit_exposure else "global"
    source = "given (--noise)" if given is not None else "unknown (no --noise)"
    return samples, capture_inputs(args.capture, args.lights, args.mask, encoding), exposure, given, source


def _target_samples(args: argparse.Namespace, png: Path):
    from strauss_fit.fitting.folder import sidecar_of
    from strauss_fit.fitting.scene_samples import samples_from_scene
    from strauss_fit.io.targets import load_target
    from strauss_fit.scene.loading import load_scene

    from .fit_cmd import parse_noise

    parse_noise(args.noise)  # a bad --noise before any work
    _check_outputs(
        args,
        png,
        {
            "TARGET": args.target,
            "TARGET's sidecar (its noise and truth)": sidecar_of(args.target),
            "--scene": args.scene,
            "--mask": args.mask,
        },
    )
    target = load_target(args.target, args.mask, args.encoding)
    samples = samples_from_scene(load_scene(args.scene), target)
    noise, source = _target_noise(args, samples, target)
    exposure = "global" if args.fit_exposure else "fixed"
    inputs = {"target": str(args.target), "scene": str(args.scene), "mask": args.mask, "encoding": args.encoding}
    return samples, inputs, exposure, noise, source

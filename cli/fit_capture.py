"""``strauss-fit fit --capture``: one material from a capture (many photographs of one sphere).

A thin shell over `strauss_fit.fitting.capture_result.fit_capture`; the options are added
to ``fit`` by `add_capture_options` (see docs/captures.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ._options import add_capture_inputs
from .common import escape, progress_printer

#: Options of ``fit`` that the capture fitter does not take: refused, never silently ignored.
NOT_TAKEN = (
    "compare",
    "resume",
    "workers",
    "scheduler",
    "render_fit",
    "manifest",
    "fit_lights",
    "noise",
    "reference_noise",
    "starts",
    "max_steps",
    "fix",
    "free",
)
#: What several targets fitted with another model than Strauss into a folder do not take:
#: `NOT_TAKEN` less what a folder of results does as a Strauss one does (``--resume``,
#: ``--manifest``).
BATCH_NOT_TAKEN = tuple(option for option in NOT_TAKEN if option not in ("resume", "manifest"))


def refuse_ignored(args: argparse.Namespace, how: str, *, scene: bool = True) -> None:
    """Refuse (one line, naming the option) an option of ``fit`` that has a default and that
    the capture fitter does not take (it is least squares by projected Levenberg–Marquardt,
    in float64, with the model's exact formulas, on the pixels the sphere covers fully),
    when given another value than its default (only that shows it was given); and, for one
    scene's targets (``scene``), ``--fit-exposure`` with a model whose scale is unbounded
    (its own parameters absorb an exposure; a capture's per-image exposures are relative and
    do apply). ``how`` ends the message."""
    from strauss_fit.errors import StraussFitError
    from strauss_fit.fitting.options import DEFAULT_QUALITY
    from strauss_fit.models.modes import DEFAULT_TABLE_SIZE
    from strauss_fit.models.reflectance import reflectance_model

    if getattr(args, "model", None) is not None:
        reflectance_model(args.model)  # an unknown model is the error, before any option it would refuse
    defaults = {
        "solver": "lm",
        "loss": "auto",
        "edge_pixels": "auto",
        "search": "auto",
        "quality": DEFAULT_QUALITY,
        "mode": "exact",
        "table_size": DEFAULT_TABLE_SIZE,
        "precision": "float64",
    }
    for option, default in defaults.items():
        if getattr(args, option, default) != default:
            raise StraussFitError(f"--{option.replace('_', '-')} is not available {how}")
    if scene and getattr(args, "fit_exposure", False) and not reflectance_model(args.model).bounded_scale:
        raise StraussFitError(
            f"--fit-exposure is not available with --model {args.model}: its scale is unbounded, so its own "
            "parameters absorb an exposure"
        )


def add_capture_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("captures (many photographs of one sphere, docs/captures.md)")
    add_capture_inputs(
        group,
        capture="a capture manifest (TOML), a folder holding capture.toml or in the DiLiGenT layout, or image files "
        "(with --lights)",
        lights="each image's lights, by order (what 'strauss-fit lights' writes)",
    )
    group.add_argument(
        "--model",
        default="strauss",
        metavar="NAME",
        help="the reflectance model fitted: strauss (the default), or another registered one (lambert, phong, "
        "blinn-phong, cook-torrance: docs/reflectance-models.md); for captures, and for one target with --scene",
    )
    group.add_argument(
        "--ambient", action="store_true", help="also fit an ambient (room) light reaching every point of the sphere"
    )
    group.add_argument("--white-balance", action="store_true", help="also fit a white balance (red and blue gains)")
    group.add_argument(
        "--stability",
        action="store_true",
        help="also fit two disjoint halves of the images (are their materials within each other's equivalence "
        "ranges?) and each image alone (where and why does it disagree with the joint fit?)",
    )
    group.add_argument(
        "--holdout",
        metavar="K|LIST",
        help="leave out every K-th image (or the 1-based images in LIST, e.g. 2,5,9), predict them, and compare "
        "with Lambert, Phong and Blinn-Phong fits of the same images",
    )


def description_files(capture) -> dict[str, Path]:
    """The files that describe ``capture`` (its manifest, or a DiLiGenT folder's lists), which
    no output may replace (``-o FOLDER/capture.toml`` with ``--capture FOLDER``)."""
    source = capture.source
    if source is None:
        return {}
    if capture.layout == "diligent":
        names = ("filenames.txt", "light_directions.txt", "light_intensities.txt")
        return {f"--capture's {name}": Path(source) / name for name in names}
    return {"--capture's manifest": Path(source)}


def run_capture(args: argparse.Namespace) -> int:
    from strauss_fit.capture import capture_inputs, open_capture
    from strauss_fit.errors import StraussFitError
    from strauss_fit.fitting.capture import CaptureFitOptions
    from strauss_fit.fitting.capture_result import fit_capture as fit_capture_api
    from strauss_fit.fitting.capture_result import format_capture_table, holdout_indices
    from strauss_fit.io.files import Outputs, check_distinct, check_writable

    from .fit_cmd import equivalence_asked

    if args.target:
        raise StraussFitError("give either TARGET images (one image each) or --capture, not both")
    if args.scene is not None:
        raise StraussFitError("a capture states its own lights and camera: --scene is for single targets")
    for option in NOT_TAKEN:
        if getattr(args, option, None):
            raise StraussFitError(f"--{option.replace('_', '-')} is not available with --capture")
    refuse_ignored(args, "with --capture", scene=False)
    if args.output.endswith(("/", "\\")):
        raise StraussFitError(f"-o {args.output} names a folder: a capture's fit writes one RESULT.json")
    paths = args.capture
    encoding = None if args.encoding == "auto" else args.encoding
    capture = open_capture(paths, args.lights, args.mask, encoding)
    inputs = {f"--capture image {i + 1}": image.path for i, image in enumerate(capture.images)}
    inputs.update({"--capture": paths[0], "--lights": args.lights, "--mask": capture.mask})
    inputs.update(description_files(capture))
    check_distinct({"-o": args.output}, inputs)
    check_writable(args.output, args.force)
    # the images to fit, before any is read
    held = holdout_indices(args.holdout, len(capture.images)) if args.holdout is not None else []
    if args.stability and len(capture.images) - len(held) < 2:
        raise StraussFitError(
            "--stability fits two halves of the images: it needs at least 2 images to fit, "
            f"not {len(capture.images) - len(held)}"
        )
    options = CaptureFitOptions(
        model=args.model,
        exposure="per-image" if args.fit_exposure else "global",
        white_balance=args.white_balance,
        ambient=args.ambient,
    )
    log = progress_printer(args.quiet, "... ")
    result = fit_capture_api(
        capture,
        options,
        holdout=args.holdout,
        progress=log,
        inputs=capture_inputs(paths, args.lights, args.mask, encoding),
        equivalence=bool(equivalence_asked(args)),
        equivalence_de=args.equivalence_de,
        stability=args.stability,
    )
    with Outputs(force=args.force) as out:
        out.add_json(args.output, result)
        written = out.commit(final=True)
    print(escape(format_capture_table(result)))
    print(f"wrote {', '.join(str(p) for p in written)}")
    return 0


def scene_model_options(args: argparse.Namespace):
    """The capture fitter's options of ``fit … --scene SCENE --model NAME``: the scene states
    the light intensities, so no exposure is fitted unless ``--fit-exposure``."""
    from strauss_fit.fitting.capture import CaptureFitOptions

    return CaptureFitOptions(
        model=args.model, exposure="global" if args.fit_exposure else "fixed", ambient=args.ambient
    )


def model_batch(args: argparse.Namespace):
    """How ``fit T1 T2 … --scene SCENE --model NAME -o OUTDIR/`` fits each target: as
    `run_scene_model` fits one (a `strauss_fit.fitting.folder.ModelFit`). An option
    the capture fitter does not take is refused, naming it."""
    from strauss_fit.errors import StraussFitError
    from strauss_fit.fitting.batch import DEFAULT_CHUNK
    from strauss_fit.fitting.folder import ModelFit

    from .fit_cmd import equivalence_asked

    for option in BATCH_NOT_TAKEN:
        if getattr(args, option, None):
            raise StraussFitError(f"--{option.replace('_', '-')} is not available with --model {args.model}")
    refuse_ignored(args, f"with --model {args.model}")
    # --chunk-size has a default, so only another value shows it was given: the targets of
    # another model are fitted one after the other (those of one size share one compiled program)
    if args.chunk_size != DEFAULT_CHUNK:
        raise StraussFitError(
            f"--chunk-size is not available with --model {args.model}: its targets are fitted one by one"
        )
    return ModelFit(
        scene_model_options(args), equivalence=bool(equivalence_asked(args)), equivalence_de=args.equivalence_de
    )


def run_scene_model(args: argparse.Namespace) -> int:
    """``fit TARGET --scene SCENE --model NAME``: another reflectance model than Strauss on one
    target (`strauss_fit.fitting.scene_samples.samples_from_scene`, then the capture
    fitter, which fits every model). Several targets go to a folder
    (`strauss_fit_cli.fit_cmd.run_batch`)."""
    from strauss_fit.errors import StraussFitError
    from strauss_fit.fitting.capture_result import fit_capture as fit_capture_api
    from strauss_fit.fitting.capture_result import format_capture_table
    from strauss_fit.fitting.folder import sidecar_of
    from strauss_fit.fitting.scene_samples import samples_from_scene
    from strauss_fit.io.files import Outputs, check_distinct, check_writable
    from strauss_fit.io.targets import load_target
    from strauss_fit.scene.loading import load_scene

    from .fit_cmd import equivalence_asked

    if args.scene is None:
        raise StraussFitError(f"--model {args.model} needs the target's scene (--scene SCENE.toml)")
    for option in NOT_TAKEN:
        if getattr(args, option, None) and option not in BATCH_NOT_TAKEN:  # a folder's: --resume
            raise StraussFitError(f"--{option} is for several targets fitted into a folder (-o OUTDIR)")
        if getattr(args, option, None):
            raise StraussFitError(f"--{option.replace('_', '-')} is not available with --model {args.model}")
    refuse_ignored(args, f"with --model {args.model}")
    target_path = args.target[0]
    check_distinct(
        {"-o": args.output},
        {
            "TARGET": target_path,
            "TARGET's sidecar (its noise and truth)": sidecar_of(target_path),
            "--scene": args.scene,
            "--mask": args.mask,
        },
    )
    check_writable(args.output, args.force)
    samples = samples_from_scene(load_scene(args.scene), load_target(target_path, args.mask, args.encoding))
    options = scene_model_options(args)
    log = progress_printer(args.quiet, "... ")
    result = fit_capture_api(
        samples,
        options,
        progress=log,
        inputs={"target": str(target_path), "scene": str(args.scene), "mask": args.mask, "encoding": args.encoding},
        equivalence=bool(equivalence_asked(args)),
        equivalence_de=args.equivalence_de,
    )
    with Outputs(force=args.force) as out:
        out.add_json(args.output, result)
        written = out.commit(final=True)
    print(escape(format_capture_table(result)))
    print(f"wrote {', '.join(str(p) for p in written)}")
    return 0

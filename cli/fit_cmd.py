"""``strauss-fit fit``: recover the Strauss parameters from a reference image."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from ._options import (
    add_equivalence_options,
    add_evaluator_options,
    add_fitting_options,
    add_force_option,
    add_image_inputs,
    add_noise_options,
    add_output_option,
    add_quality_option,
    add_quiet_option,
    add_search_options,
)
from .common import (
    bounded_int,
    by_quality,
    check_evaluator_options,
    escape,
    positive_int,
    progress_printer,
)

#: Local Dask workers per CPU at most (--workers): each is a process with its own JAX
#: runtime and compiled programs, so more than a couple per core only costs memory and
#: start-up; beyond that a cluster belongs on --scheduler.
WORKERS_PER_CPU = 2
MAX_WORKERS = WORKERS_PER_CPU * (os.cpu_count() or 1)


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "fit",
        help="fit the Strauss parameters to reference images",
        description="Fit the material (C, s, m, t, n) of SCENE to the image TARGET by least squares "
        "(optimistix), in float64, from several starts. Parameters the scene cannot constrain are "
        "held at the scene's [material] values and the result says why; the fit then says whether "
        "the model reproduces the target within its noise. Writes RESULT.json. Several targets (files, "
        "folders, @LIST files, or --manifest) are fitted together into the folder -o OUTDIR: "
        "OUTDIR/<stem>.json per target and OUTDIR/summary.csv (see docs/commands/fit.md).",
    )
    add_image_inputs(
        parser,
        target=dict(
            nargs="*",
            help="reference image(s) (.exr/.hdr/.tif linear; .png/.jpg sRGB), folders of images, or @LIST files",
        ),
        scene="the scene the target(s) were taken in",
        encoding="how TARGET's values are encoded (default: sRGB for .png/.jpg, linear otherwise)",
    )
    add_output_option(parser, metavar="RESULT.json|OUTDIR", help="fit result (JSON), or a folder")
    add_fitting_options(parser)
    parser.add_argument(
        "--max-steps",
        type=positive_int,
        metavar="N",
        help=f"solver step limit of the polish (default: from --quality: {by_quality('max_steps')})",
    )
    add_noise_options(parser)
    add_search_options(parser)
    parser.add_argument(
        "--fit-exposure", action="store_true", help="also fit one global exposure (a scale on the whole image)"
    )
    add_equivalence_options(parser)
    parser.add_argument(
        "--render-fit",
        metavar="OUT",
        help="write the fitted image to OUT and a target | fit | residual | residual/noise PNG beside it "
        "(OUT.compare.png); one target only",
    )
    add_force_option(parser)
    add_quiet_option(parser, "print only the result table")
    from .fit_capture import add_capture_options

    add_capture_options(parser)
    _add_batch_options(parser.add_argument_group("several targets (-o is a folder)"))
    add_evaluator_options(parser)
    add_quality_option(parser)
    parser.set_defaults(run=run)


def _add_batch_options(batch: argparse._ArgumentGroup) -> None:
    """The options of several targets fitted into a folder."""
    batch.add_argument(
        "--manifest",
        metavar="FILE",
        help="CSV or JSON list of targets with their own scene, mask, encoding (columns target, scene, mask, encoding)",
    )
    batch.add_argument("--compare", action="store_true", help="also write OUTDIR/<stem>.compare.png per target")
    batch.add_argument(
        "--resume", action="store_true", help="keep the results already in OUTDIR and fit the other targets"
    )
    batch.add_argument(
        "--chunk-size",
        type=positive_int,
        default=64,
        metavar="N",
        help="targets fitted together (one compiled call covers up to N; default 64)",
    )
    batch.add_argument(
        "--workers",
        type=bounded_int(1, MAX_WORKERS),
        metavar="N",
        help=f"run on a local Dask cluster of N worker processes (at most {WORKERS_PER_CPU} per CPU: {MAX_WORKERS} "
        "here; a larger cluster runs on --scheduler)",
    )
    batch.add_argument("--scheduler", metavar="ADDRESS", help="run on the Dask cluster at ADDRESS (tcp://host:8786)")


def parse_fixed(items: list[str]) -> tuple[tuple[str, float | tuple[float, ...]], ...]:
    import math

    from strauss_fit.errors import StraussFitError

    fixed = []
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or not name:
            raise StraussFitError(f"--fix expects NAME=VALUE, got {item!r}")
        if any(name == earlier for earlier, _ in fixed):  # not the last one silently
            raise StraussFitError(f"--fix {name} is given twice: give each parameter one value")
        try:
            numbers = tuple(float(v) for v in text.split(","))
        except ValueError:
            raise StraussFitError(f"--fix {name}: {text!r} is not a number (or R,G,B for color)") from None
        if not all(math.isfinite(v) for v in numbers):
            raise StraussFitError(f"--fix {name}: {text!r} is not a finite number")
        if name == "color":
            if len(numbers) != 3:
                raise StraussFitError(f"--fix color expects R,G,B, got {text!r}")
            fixed.append((name, numbers))
        else:
            if len(numbers) != 1:
                raise StraussFitError(f"--fix {name} expects one number, got {text!r}")
            fixed.append((name, numbers[0]))
    return tuple(fixed)


def fit_options(args: argparse.Namespace, fixed, **more):
    """The `FitOptions` of ``--quality`` with the options
    given explicitly (also used by ``sample`` when it fits first)."""
    from strauss_fit import FitOptions

    options = FitOptions.preset(
        args.quality,
        solver=args.solver,
        starts=args.starts,
        mode=args.mode,
        table_size=args.table_size,
        free=_free_names(args.free),
        fixed=fixed,
        fit_lights=args.fit_lights,
        noise=parse_noise(getattr(args, "noise", None)),
        loss=getattr(args, "loss", None),
        fit_exposure=getattr(args, "fit_exposure", None),
        edge_pixels=getattr(args, "edge_pixels", None),
        search=getattr(args, "search", None),
        equivalence=equivalence_asked(args),
        equivalence_de=getattr(args, "equivalence_de", None),
        **more,
    )
    options.validate()
    return options


def equivalence_asked(args: argparse.Namespace) -> bool | None:
    """``--equivalence`` as given; a threshold (``--equivalence-de``) alone asks for the
    ranges too (the threshold means nothing without them), and with ``--no-equivalence``
    it is a contradiction."""
    from strauss_fit.errors import StraussFitError

    equivalence = getattr(args, "equivalence", None)
    if getattr(args, "equivalence_de", None) is None:
        return equivalence
    if equivalence is False:
        raise StraussFitError("--equivalence-de sets the threshold of --equivalence, which --no-equivalence turns off")
    return True


def parse_noise(text: str | None) -> float | tuple[float, float, float] | None:
    """``--noise``: one positive number, or R,G,B."""
    import math

    from strauss_fit.errors import StraussFitError

    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise StraussFitError(f"--noise expects a number or R,G,B, got {text!r}") from None
    if len(values) not in (1, 3) or not all(math.isfinite(v) and v > 0 for v in values):
        raise StraussFitError(f"--noise expects one positive number or three (R,G,B), got {text!r}")
    return values[0] if len(values) == 1 else values


def check_fixed_ranges(fixed) -> None:
    from strauss_fit import Material
    from strauss_fit.models.material import PARAMETER_NAMES

    material_values = {k: (list(v) if k == "color" else v) for k, v in fixed if k in PARAMETER_NAMES}
    Material.from_dict(material_values)  # raises a one-line MaterialError naming field and range
    for name, value in fixed:
        if "intensity" in name and value < 0:
            from strauss_fit.errors import StraussFitError

            raise StraussFitError(f"--fix {name}={value}: an intensity must be >= 0")


def is_batch(args: argparse.Namespace) -> bool:
    """Several targets (into a folder) or one (into RESULT.json)?"""
    output = Path(args.output)
    return (
        len(args.target) != 1
        or args.manifest is not None
        or args.target[0].startswith("@")
        or Path(args.target[0]).is_dir()
        or output.is_dir()
        or args.output.endswith(("/", "\\"))
    )


def _free_names(text: str | None) -> tuple[str, ...] | None:
    """``--free a,b``'s names; None (the automatic choice) when not given. Given but naming
    nothing (``--free ''``, ``--free ,``) is refused: a script whose variable came out empty
    meant some parameters, not the automatic choice."""
    if text is None:
        return None
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if not names:
        from strauss_fit.errors import StraussFitError

        raise StraussFitError(f"--free {text!r} names no parameter (leave it out for the automatic choice)")
    return names


def check_outputs(args: argparse.Namespace) -> Path | None:
    """Check every output of ``fit`` before any work; returns the comparison image's path."""
    from strauss_fit.errors import StraussFitError
    from strauss_fit.io.files import check_distinct, check_writable
    from strauss_fit.io.images import check_image_output

    for option in ("compare", "resume", "workers", "scheduler"):
        if getattr(args, option):
            raise StraussFitError(f"--{option} is for several targets fitted into a folder (-o OUTDIR)")
    if args.scene is None:
        raise StraussFitError("give --scene (the scene the target was taken in)")
    from strauss_fit.fitting.folder import sidecar_of

    compare_path = Path(args.render_fit).with_suffix(".compare.png") if args.render_fit else None
    check_distinct(
        {"-o": args.output, "--render-fit": args.render_fit, "--render-fit's comparison": compare_path},
        {
            "TARGET": args.target[0],
            "TARGET's sidecar (its noise and truth)": sidecar_of(args.target[0]),
            "--scene": args.scene,
            "--mask": args.mask,
        },
    )
    check_writable(args.output, args.force)
    if args.render_fit:
        check_image_output(args.render_fit, args.force)
        check_image_output(compare_path, args.force)
    return compare_path


def run(args: argparse.Namespace) -> int:
    check_evaluator_options(args)
    if not args.output.strip():
        from strauss_fit.errors import StraussFitError

        raise StraussFitError("-o is empty: give a RESULT.json, or a folder (OUTDIR/) for several targets")
    if args.capture:
        from .fit_capture import run_capture

        return run_capture(args)
    for option in ("lights", "ambient", "white_balance", "holdout", "stability"):
        if getattr(args, option):
            from strauss_fit.errors import StraussFitError

            raise StraussFitError(f"--{option.replace('_', '-')} is for captures (--capture)")
    if is_batch(args):
        return run_batch(args)
    if args.model != "strauss":
        from .fit_capture import run_scene_model

        return run_scene_model(args)
    compare_path = check_outputs(args)
    fixed = parse_fixed(args.fix)
    check_fixed_ranges(fixed)
    options = fit_options(args, fixed, max_steps=args.max_steps, reference_noise=args.reference_noise)

    from strauss_fit import fit, load_scene, load_target, match_scene
    from strauss_fit.fitting.summary import comparison_image, format_fit_table, standardized_map
    from strauss_fit.io.files import Outputs
    from strauss_fit.io.images import add_image

    log = progress_printer(args.quiet, "... ")
    scene = load_scene(args.scene)
    target = load_target(args.target[0], args.mask, args.encoding)
    scene, message = match_scene(scene, target)
    if message:
        log(message)
    if args.precision != "float64":
        log("fits always run in float64; --precision is ignored")
    result = fit(scene, target, options, progress=log)
    payload = merged(result.to_json(), recorded(args, args.target[0], args.scene, args.mask, args.encoding))
    with Outputs(force=args.force) as out:  # all or nothing
        out.add_json(args.output, payload)
        if args.render_fit:
            add_image(out, args.render_fit, result.fitted_image)
            # the target as fitted: a target above the pixel limit was fitted block-averaged
            seen = result.target_image if result.target_image is not None else target.pixels
            standardized = standardized_map(result, seen.shape[:2])
            add_image(out, compare_path, comparison_image(seen, result.fitted_image, result.mask, standardized))
        written = out.commit(final=True)
    print(escape(format_fit_table(payload)))
    print(f"wrote {', '.join(str(p) for p in written)}")
    return 0 if result.solver["status"] == "successful" else 1


def merged(payload: dict, extra: dict) -> dict:
    """``payload`` with ``extra``'s keys (a dict value is merged into the dict there)."""
    for key, value in extra.items():
        if isinstance(value, dict) and isinstance(payload.get(key), dict):
            payload[key].update(value)
        else:
            payload[key] = value
    return payload


def recorded(args: argparse.Namespace, target, scene, mask, encoding) -> dict:
    """What the command line records in a result JSON beside the fit itself."""
    return {
        "target": str(target),
        "scene": str(scene),
        "mask": str(mask) if mask else None,
        "encoding": encoding,
        "settings": {"quality": args.quality},
    }


def run_batch(args: argparse.Namespace) -> int:
    """Several targets into the folder ``-o`` (`strauss_fit.fitting.folder.fit_to_folder`),
    with the Strauss fit or, with ``--model NAME``, another reflectance model (each target as
    `strauss_fit_cli.fit_capture.run_scene_model` fits one)."""
    import sys
    import time

    from strauss_fit import FitOptions
    from strauss_fit.errors import StraussFitError
    from strauss_fit.fitting.folder import fit_to_folder, jobs_from_arguments

    model = None
    if args.model != "strauss":
        from .fit_capture import model_batch

        model = model_batch(args)  # refuses first what the capture fitter does not take
    if args.render_fit:
        raise StraussFitError("--render-fit writes one target's images; with several targets use --compare")
    if args.workers is not None and args.scheduler is not None:
        raise StraussFitError("give --workers or --scheduler, not both")
    if args.resume and args.force:
        raise StraussFitError("give --resume or --force, not both")
    if model is None:
        fixed = parse_fixed(args.fix)
        check_fixed_ranges(fixed)
        options = fit_options(args, fixed, max_steps=args.max_steps, reference_noise=args.reference_noise)
    else:
        options = FitOptions()  # the jobs' Strauss options, unused: ``model`` says how each is fitted
    jobs = jobs_from_arguments(args.target, args.scene, args.manifest, options, mask=args.mask, encoding=args.encoding)
    executor = None
    if args.workers is not None or args.scheduler is not None:
        from strauss_fit.fitting.executors import DaskExecutor

        executor = DaskExecutor(args.workers, scheduler=args.scheduler)
    log = progress_printer(args.quiet, "")
    listed = [argument[1:] for argument in args.target if argument.startswith("@")]
    bar = ProgressBar(args.quiet)

    def record(job):
        return recorded(args, job.target, job.scene, job.mask, job.encoding)

    def announce(index, result):
        from strauss_fit.fitting.batch import FitFailure

        if isinstance(result, FitFailure):
            bar.clear()
            log(f"fit: failed: {escape(str(result))}")

    started = time.perf_counter()
    run = fit_to_folder(
        jobs,
        args.output,
        executor=executor,
        chunk_size=args.chunk_size,
        resume=args.resume,
        force=args.force,
        compare=args.compare,
        # another model's result records its inputs itself, as the single --model fit writes it
        recorded=record if model is None else None,
        progress=bar.update,
        on_result=announce,
        inputs=[*listed, *([args.manifest] if args.manifest else [])],
        log=log,
        model=model,
    )
    bar.clear()
    elapsed = time.perf_counter() - started
    rate = run.fitted / elapsed if elapsed > 0 else 0.0
    print(
        f"{run.fitted} fitted, {run.failed} failed, {run.skipped} kept from before, of {len(jobs)} target(s) "
        f"in {elapsed:.1f} s ({rate:.1f} targets/s); wrote {run.summary}",
        file=sys.stdout,
    )
    return 1 if run.failed else 0


class ProgressBar:
    """One status line on stderr: targets done, rate, time left, failures (redrawn in
    place on a terminal; elsewhere a line every tenth of the way)."""

    def __init__(self, quiet: bool):
        import sys

        self.quiet = quiet
        self.stream = sys.stderr
        self.tty = self.stream.isatty()
        self.shown = 0
        self.last = -1

    def update(self, progress) -> None:
        from . import interrupts

        interrupts.check()
        if self.quiet:
            return
        eta = "?" if progress.eta_s is None else _duration(progress.eta_s)
        text = (
            f"fit: {progress.done}/{progress.total} ({100 * progress.done / progress.total:.0f} %), "
            f"{progress.rate:.1f} targets/s, {eta} left, {progress.failed} failed"
        )
        if self.tty:
            self.stream.write("\r" + text.ljust(self.shown))
            self.stream.flush()
            self.shown = len(text)
        else:
            step = max(progress.total // 10, 1)
            if progress.done // step != self.last or progress.done == progress.total:
                self.last = progress.done // step
                print(text, file=self.stream, flush=True)

    def clear(self) -> None:
        if self.tty and self.shown and not self.quiet:
            self.stream.write("\r" + " " * self.shown + "\r")
            self.stream.flush()
            self.shown = 0


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 60}m{seconds % 60:02d}s" if seconds >= 60 else f"{seconds}s"

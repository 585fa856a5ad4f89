"""``strauss-fit render``: render a scene file to an image."""

from __future__ import annotations

import argparse
import dataclasses
import sys

from strauss_fit.io.table_formats import IMAGE_FORMATS, describe_image_formats, describe_suffixes

from ._options import add_evaluator_options, add_force_option, add_output_option
from .common import check_evaluator_options, image_side, positive_int


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "render",
        help="render a scene file to an image",
        description=f"Render the sphere of SCENE (its [material]) to OUT, in the format its extension names: "
        f"{describe_image_formats()}.",
    )
    parser.add_argument("scene", metavar="SCENE.toml", help="scene file (see docs/formats.md, 'Scene files')")
    add_output_option(parser, metavar="OUT", help=f"output image ({describe_suffixes(IMAGE_FORMATS)})")
    parser.add_argument(
        "--width", type=image_side, help="override the camera's width in pixels (at most 8192, as in scene files)"
    )
    parser.add_argument(
        "--height", type=image_side, help="override the camera's height in pixels (at most 8192, as in scene files)"
    )
    parser.add_argument(
        "--depth",
        type=positive_int,
        help="recursion depth of the global model (1 = local model only, at most 64); default: the scene's. "
        "Traced only as deep as it changes the written image (see docs/commands/render.md)",
    )
    parser.add_argument("--mask", metavar="MASK_OUT", help="also write the sphere mask (white = sphere)")
    parser.add_argument(
        "--model",
        metavar="NAME",
        help="render another registered reflectance model (lambert, phong, blinn-phong, cook-torrance, or strauss "
        "as a local, opaque model) instead of the scene's Strauss [material]: docs/reflectance-models.md",
    )
    parser.add_argument(
        "--values",
        metavar="VALUES.json",
        help="with --model: the model's parameters, a JSON object of them or a fit result (its 'values'); "
        "missing ones take the model's defaults",
    )
    add_force_option(parser)
    add_evaluator_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    check_evaluator_options(args)
    from strauss_fit.errors import StraussFitError
    from strauss_fit.io.files import check_distinct
    from strauss_fit.io.images import check_image_output

    # every output checked before any work
    check_distinct({"-o": args.output, "--mask": args.mask}, {"SCENE": args.scene, "--values": args.values})
    check_image_output(args.output, args.force)
    if args.mask:
        check_image_output(args.mask, args.force)
    if args.depth is not None and args.depth > 64:
        raise StraussFitError(f"--depth must be from 1 to 64, got {args.depth}")

    import jax.numpy as jnp

    from strauss_fit import load_scene, render
    from strauss_fit.rendering.strauss import OUTPUT_TOLERANCE, depth_messages

    scene = load_scene(args.scene)
    if args.width or args.height:
        scene = scene.resized(args.width or scene.camera.width, args.height or scene.camera.height)
    if args.values and not args.model:
        raise StraussFitError("--values gives a --model's parameters: give --model too")
    if args.model:
        return _run_model(args, scene)
    if args.depth:
        scene = dataclasses.replace(scene, depth=args.depth)
    # the file holds float32 (or 8 bits): deeper bounces than it can show are not traced
    for message in depth_messages(scene, tolerance=OUTPUT_TOLERANCE):
        print(f"render: {message}", file=sys.stderr, flush=True)
    image, mask = render(
        scene,
        mode=args.mode,
        table_size=args.table_size,
        dtype=jnp.dtype(args.precision),
        depth_tolerance=OUTPUT_TOLERANCE,
    )
    return _write(args, image, mask, "")


def _run_model(args: argparse.Namespace, scene) -> int:
    """``render --model NAME``: `strauss_fit.rendering.reflectance.render_model`."""

    from strauss_fit.errors import StraussFitError
    from strauss_fit.io.files import read_json
    from strauss_fit.models.reflectance import reflectance_model
    from strauss_fit.rendering.reflectance import render_model

    reflectance_model(args.model)  # an unknown name before the values are read
    values = {}
    if args.values:
        data = read_json(args.values, "--values")
        if not isinstance(data, dict):
            raise StraussFitError(f"--values {args.values} must hold a JSON object of the model's parameters")
        if not isinstance(data.get("values"), dict) and {"free", "models", "kind", "residual", "settings"} & set(data):
            # another command's result: a Strauss fit of one image, a comparison, a chain's summary
            raise StraussFitError(
                f"--values {args.values} is a result without a model's 'values' (not of 'fit --model' or "
                "'fit --capture'): give such a result, or a JSON object of the model's parameters"
            )
        if isinstance(data.get("values"), dict):  # a fit result
            if data.get("model", args.model) != args.model:
                raise StraussFitError(f"--values {args.values} is a {data.get('model')} fit, not {args.model}")
            data = data["values"]
        values = {k: v for k, v in data.items() if k not in ("exposure", "image_exposure", "white_balance", "ambient")}
    image, mask = render_model(scene, args.model, values)
    return _write(args, image, mask, f", model {args.model}")


def _write(args: argparse.Namespace, image, mask, detail: str) -> int:
    """Write the image and, with ``--mask``, the mask together (all or nothing), and say so."""
    import numpy as np

    from strauss_fit.io.files import Outputs
    from strauss_fit.io.images import add_image

    with Outputs(force=args.force) as out:
        add_image(out, args.output, np.asarray(image))
        if args.mask:
            mask_rgb = np.repeat(np.asarray(mask, dtype=float)[..., None], 3, axis=-1)
            add_image(out, args.mask, mask_rgb, encoding="linear")
        out.commit(final=True)
    height, width = mask.shape
    print(f"wrote {args.output} ({width}x{height}, {int(np.sum(mask))} sphere pixels{detail})")
    return 0

"""``strauss-fit render``: render a scene file to an image."""

from __future__ import annotations

import argparse
import dataclasses

from .common import add_evaluator_options, check_evaluator_options, positive_int


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "render",
        help="render a scene file to an image",
        description="Render the sphere of SCENE (its [material]) to OUT. .exr/.hdr/.tif are written "
        "as linear float; .png/.jpg are sRGB-encoded and clipped to 8 bits.",
    )
    parser.add_argument("scene", metavar="SCENE.toml", help="scene file (see README, 'Scene file')")
    parser.add_argument("-o", "--output", required=True, metavar="OUT", help="output image")
    parser.add_argument("--width", type=positive_int, help="override the camera's width in pixels")
    parser.add_argument("--height", type=positive_int, help="override the camera's height in pixels")
    parser.add_argument(
        "--depth",
        type=positive_int,
        help="recursion depth of the global model (1 = local model only); default: the scene's",
    )
    parser.add_argument("--mask", metavar="MASK_OUT", help="also write the sphere mask (white = sphere)")
    parser.add_argument("--force", action="store_true", help="overwrite existing outputs")
    add_evaluator_options(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    check_evaluator_options(args)
    import jax.numpy as jnp
    import numpy as np

    from strauss_fit import load_scene, render, write_image
    from strauss_fit.io.files import check_writable

    check_writable(args.output, args.force)
    if args.mask:
        check_writable(args.mask, args.force)
    scene = load_scene(args.scene)
    if args.width or args.height:
        scene = scene.resized(args.width or scene.camera.width, args.height or scene.camera.height)
    if args.depth:
        scene = dataclasses.replace(scene, depth=args.depth)
    image, mask = render(scene, mode=args.mode, table_size=args.table_size, dtype=jnp.dtype(args.precision))
    write_image(args.output, np.asarray(image), force=args.force)
    if args.mask:
        write_image(
            args.mask,
            np.repeat(np.asarray(mask, dtype=float)[..., None], 3, axis=-1),
            force=args.force,
            encoding="linear",
        )
    height, width = mask.shape
    print(f"wrote {args.output} ({width}x{height}, {int(np.sum(mask))} sphere pixels)")
    return 0

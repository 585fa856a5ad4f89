"""Regenerate the bundled Mitsuba 3 targets, ``data_synth/bundled_mitsuba``
(`data_synth.BUNDLED_MITSUBA`).

Usage (needs Mitsuba 3, ``pip install -e '.[mitsuba]'``; about 3 minutes with
``llvm_ad_rgb`` on two cores, 4-10 times longer with ``scalar_rgb``)::

    python -m data_synth.make_bundled_mitsuba --out /tmp/mitsuba-set        # a new or empty folder
    python -m data_synth.make_bundled_mitsuba --out /tmp/mitsuba-set --only mitsuba-diffuse-0000
    python -m data_synth.make_bundled_mitsuba --force                       # replace the bundled set

Options: ``--out DIR`` (default: the bundled folder), ``--variant`` (``llvm_ad_rgb``, the
variant of the bundled set, when it loads, else ``scalar_rgb``), ``--only ID ...`` (render
these samples only, even if intact; the index lists the others as pending unless they are
kept by ``--resume``), ``--force`` (replace the dataset in a non-empty folder: the files its
index lists) or ``--resume`` (keep the intact samples of an earlier run of the same plan).

The set is `GROUPS`, stated here because a dataset spec (`data_synth.spec`)
cannot select the Mitsuba backend; ``index.json`` names this file as its ``spec``. Ids,
order and seeds follow synth's rules (`data_synth.plan`): sample j of group g is every
BSDF of the group in every scene of it, BSDF-major, with the id ``NAME-jjjj``; its two
Mitsuba seeds are ``SeedSequence(SEED, spawn_key=(2, g, j)).generate_state(2)`` (stream 2,
beside synth's 0 for parameter draws and 1 for sensor noise).

Per sample (64 x 64, no sensor noise), written together through
`strauss_fit.io.files.Outputs` (all or none), then the index (atomically):

- ``ID.exr``: the mean of two renders (`SPP` samples per pixel each, one seed each),
  linear float32, PXR24 compression, no timestamp;
- ``ID.coverage.exr``: each pixel's coverage by the sphere (one channel ``Y``, float32, zip);
- ``ID.mask.png``: 255 on the fully covered pixels;
- ``ID.json``: a synth sidecar (``"format": "strauss-fit synth sample"``, ``"model":
  "mitsuba"``, the complete BSDF as ``parameters``) with ``render`` (Mitsuba's settings,
  seeds, version, wall-clock ``seconds``, the scene translation), ``noise`` (the measured
  Monte Carlo noise: std(a - b)/2 of the two renders a, b over the fully covered pixels,
  with the EXR's quantization added in quadrature), ``image`` and, where a person would
  name a body colour (`body_bsdf`), ``reference.diffuse_albedo``: the same BSDF with
  its specular reflection off, divided by a white Lambertian render of the scene (both
  `REFERENCE_SPP` samples per pixel, the sample's first seed), the median over the
  fully covered pixels lit at more than half the peak.

Reproducibility: two runs with the same variant and Mitsuba version give byte-identical
images, coverage images and masks, and sidecars that differ only in ``render.seconds``. The
bundled set was made with ``llvm_ad_rgb`` and Mitsuba 3.9.1: a run reproduces its images
byte for byte; its sidecars differ besides in the studio target's environment path (the
bundled one is the absolute path of the machine that made it) and in
``reference.diffuse_albedo`` by at most 2e-4 (the seeds of its reference renders were not
recorded). ``scalar_rgb`` draws other noise, so its images differ from the bundled ones
within the recorded noise.
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import json
import sys
import time
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from strauss_fit.errors import StraussFitError
from strauss_fit.io.files import Outputs

from . import BUNDLED_MITSUBA, SCENES
from . import mitsuba_backend as mb
from .files import decode_exr, float_exr_bytes, mask_bytes, sha256_bytes
from .index import INDEX_FORMAT, INDEX_NAME, INDEX_VERSION, write_index

#: The bundled set's folder, the default output (`data_synth.BUNDLED_MITSUBA`).
OUTPUT = BUNDLED_MITSUBA
#: The scene files the cases name (`data_synth.SCENES`).
SCENE_DIR = SCENES
#: What ``index.json`` names as the dataset's spec.
SPEC_NAME = "make_bundled_mitsuba.py"

SIDECAR_FORMAT = "strauss-fit synth sample"
SEED = 2026
DESCRIPTION = (
    "strauss-fit bundled Mitsuba 3 targets: Lambertian calibration, plastics, measured metals, principled, glass"
)
#: Samples per pixel of each of the two renders of a sample.
SPP = 4096
RENDERS = 2
#: Spawn-key stream of the Mitsuba seeds (synth: 0 parameter draws, 1 sensor noise).
MITSUBA_STREAM = 2
#: The variant the bundled set was rendered with (byte-identical images need it).
VARIANT = "llvm_ad_rgb"
IMAGE_COMPRESSION = "pxr24"
COVERAGE_COMPRESSION = "zip"
NO_SENSOR = {"exposure": 1.0, "gain": 0.0, "read_noise": 0.0}
#: Samples per pixel of the two renders behind ``reference.diffuse_albedo``.
REFERENCE_SPP = 256
REFERENCE_HOW = (
    "the body as Mitsuba renders it: the same BSDF with its specular reflection off (plastic: "
    "specular_reflectance 0; principled: specular 0), 256 samples per pixel, divided by a white Lambertian "
    "render of the scene, median over the fully covered pixels lit at more than half the peak; for a rough "
    "plastic it is well below diffuse_reflectance (the rough coat transmits less)"
)
NOISE_METHOD = (
    "two renders with independent seeds a, b; the image is (a + b)/2, its Monte Carlo noise std(a - b)/2 per "
    "channel over fully covered pixels (it varies across the sphere: larger in highlights and reflections); "
    "per_channel adds the EXR quantization in quadrature"
)


@dataclass(frozen=True)
class Group:
    """Samples rendered alike: every BSDF of ``bsdfs`` (Mitsuba parameters, completed by
    `validate_bsdf`) in every scene of ``scenes`` (names
    of ``data_synth/scenes/NAME.toml``), ``size`` (width, height) overriding the scenes'."""

    name: str
    scenes: tuple[str, ...]
    bsdfs: tuple[dict[str, Any], ...]
    size: tuple[int, int] | None = None
    spp: int = SPP
    note: str = ""


#: The bundled set, in order (group g of the seeds' spawn keys is the position here).
GROUPS: tuple[Group, ...] = (
    Group(
        "mitsuba-diffuse",
        ("key_light",),
        ({"type": "diffuse", "reflectance": [0.8, 0.5, 0.2]},),
        note="the calibration case: strauss-fit s = m = t = 0 matches it up to Strauss's off-specular term",
    ),
    Group(
        "mitsuba-diffuse-two",
        ("two_lights",),
        ({"type": "diffuse", "reflectance": [0.25, 0.45, 0.7]},),
        note="a second albedo under two coloured directional lights",
    ),
    Group(
        "mitsuba-plastic",
        ("key_light",),
        ({"type": "plastic", "diffuse_reflectance": [0.8, 0.6, 0.1], "int_ior": 1.5},),
        note="smooth plastic: a delta coat (the lights' highlights are invisible), the ambient sky at the rim",
    ),
    Group(
        "mitsuba-roughplastic-yellow",
        ("key_light",),
        (
            {
                "type": "roughplastic",
                "distribution": "ggx",
                "alpha": 0.1,
                "diffuse_reflectance": [0.8, 0.6, 0.1],
                "int_ior": 1.5,
            },
        ),
        note="rough plastic, GGX alpha 0.1",
    ),
    Group(
        "mitsuba-roughplastic-blue",
        ("key_light",),
        (
            {
                "type": "roughplastic",
                "distribution": "ggx",
                "alpha": 0.3,
                "diffuse_reflectance": [0.2, 0.4, 0.8],
                "int_ior": 1.5,
            },
        ),
        note="rough plastic, GGX alpha 0.3",
    ),
    Group(
        "mitsuba-roughplastic-green",
        ("two_lights", "point_light"),
        (
            {
                "type": "roughplastic",
                "distribution": "ggx",
                "alpha": 0.2,
                "diffuse_reflectance": [0.2, 0.5, 0.3],
                "int_ior": 1.5,
            },
        ),
        note="rough plastic under two coloured lights, and under a near point light (perspective)",
    ),
    Group(
        "mitsuba-roughconductor",
        ("key_light",),
        (
            {"type": "roughconductor", "distribution": "ggx", "alpha": 0.2, "material": "Au"},
            {"type": "roughconductor", "distribution": "ggx", "alpha": 0.2, "material": "Cu"},
        ),
        note="measured rough metals: gold, copper",
    ),
    Group(
        "mitsuba-conductor-studio",
        ("metal_environment",),
        ({"type": "conductor", "material": "Ag"},),
        size=(64, 64),
        note="polished silver reflecting the studio environment (perspective, directional + point light)",
    ),
    Group(
        "mitsuba-principled-dielectric",
        ("key_light",),
        ({"type": "principled", "base_color": [0.7, 0.2, 0.2], "metallic": 0.0, "roughness": 0.4},),
        note="Disney principled, a dielectric",
    ),
    Group(
        "mitsuba-principled-metal",
        ("key_light",),
        ({"type": "principled", "base_color": [0.9, 0.6, 0.3], "metallic": 1.0, "roughness": 0.3},),
        note="Disney principled, a metal (Mitsuba's alpha = roughness^2)",
    ),
    Group(
        "mitsuba-glass",
        ("checker",),
        ({"type": "dielectric", "int_ior": 1.5},),
        note="clear glass before the checkerboard",
    ),
)


@dataclass(frozen=True)
class BundledSample:
    """One planned sample: the complete BSDF, the scene (``file`` relative to the output
    folder and to ``data_synth/specs``, ``definition`` as rendered) and its seeds."""

    id: str
    group: str
    group_index: int
    index: int
    bsdf: dict[str, Any]
    scene_name: str
    scene_file: str
    definition: dict[str, Any] = field(repr=False)
    spp: int
    seeds: tuple[int, int]

    @property
    def spawn_key(self) -> list[int]:
        return [MITSUBA_STREAM, self.group_index, self.index]


def seeds(spawn_key: Sequence[int], entropy: int = SEED) -> tuple[int, int]:
    """The two Mitsuba seeds (uint32) of the sample with this spawn key."""
    state = np.random.SeedSequence(entropy, spawn_key=tuple(spawn_key)).generate_state(RENDERS, dtype=np.uint32)
    return int(state[0]), int(state[1])


def load_definition(name: str, size: tuple[int, int] | None = None) -> dict[str, Any]:
    """The mapping of ``data_synth/scenes/NAME.toml`` as rendered: ``[material]`` removed,
    the camera size overridden by ``size``."""
    definition = tomllib.loads((SCENE_DIR / f"{name}.toml").read_text(encoding="utf-8"))
    definition.pop("material", None)
    if size is not None:
        definition["camera"]["width"], definition["camera"]["height"] = size
    return definition


def plan(groups: Sequence[Group] = GROUPS) -> list[BundledSample]:
    """Every sample of the set, in order (no Mitsuba needed). The BSDFs and scenes are
    validated (one-line `MitsubaBackendError`)."""
    samples = []
    for g, group in enumerate(groups):
        bsdfs = [mb.validate_bsdf(b, f"{group.name}: bsdf") for b in group.bsdfs]
        scenes = []
        for name in group.scenes:
            definition = load_definition(name, group.size)
            mb.translate_scene(definition, SCENE_DIR)  # validates the scene and its lights
            scenes.append((name, definition))
        j = 0
        for bsdf in bsdfs:
            for name, definition in scenes:
                samples.append(
                    BundledSample(
                        id=f"{group.name}-{j:04d}",
                        group=group.name,
                        group_index=g,
                        index=j,
                        bsdf=bsdf,
                        scene_name=name,
                        scene_file=f"../scenes/{name}.toml",
                        definition=copy.deepcopy(definition),
                        spp=group.spp,
                        seeds=seeds([MITSUBA_STREAM, g, j]),
                    )
                )
                j += 1
    return samples


def describe(sample: BundledSample, variant: str = VARIANT) -> dict[str, Any]:
    """Everything that determines a sample's files: the sidecar's first keys."""
    return {
        "id": sample.id,
        "group": sample.group,
        "index": sample.index,
        "model": "mitsuba",
        "parameters": sample.bsdf,
        "scene": {"name": sample.scene_name, "file": sample.scene_file, "definition": sample.definition},
        "sensor": dict(NO_SENSOR),
        "formats": ["exr"],
        "seed": {"entropy": SEED, "spawn_key": sample.spawn_key},
        "render": {"spp": sample.spp, "renders": RENDERS, "variant": variant},
    }


def plan_digest(samples: Sequence[BundledSample], variant: str = VARIANT) -> str:
    """SHA-256 of every sample's description (synth's ``plan_sha256``)."""
    text = json.dumps([describe(s, variant) for s in samples], sort_keys=True, allow_nan=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def sample_files(sample: BundledSample) -> dict[str, str]:
    """The file names of a sample by role (``exr``, ``coverage``, ``mask``, ``sidecar``)."""
    return {
        "exr": f"{sample.id}.exr",
        "coverage": f"{sample.id}.coverage.exr",
        "mask": f"{sample.id}.mask.png",
        "sidecar": f"{sample.id}.json",
    }


def body_bsdf(bsdf: dict[str, Any]) -> dict[str, Any] | None:
    """The BSDF's body without its specular reflection, for the targets where a person
    would name a body colour (Lambertian, plastics, a principled dielectric); else None."""
    kind = bsdf["type"]
    if kind == "diffuse":
        return dict(bsdf)
    if kind in ("plastic", "roughplastic"):
        return {**bsdf, "specular_reflectance": 0.0}
    if kind == "principled" and bsdf.get("metallic", 0.0) == 0.0 and bsdf.get("spec_trans", 0.0) == 0.0:
        return {**{k: v for k, v in bsdf.items() if k != "eta"}, "specular": 0.0}
    return None


def reference_albedo(sample: BundledSample, variant: str) -> list[float] | None:
    """``reference.diffuse_albedo`` of a sample (see the module docstring), or None."""
    body = body_bsdf(sample.bsdf)
    if body is None:
        return None
    seed = sample.seeds[0]
    kwargs = {"spp": REFERENCE_SPP, "seed": seed, "variant": variant, "base_dir": SCENE_DIR}
    rendered = mb.render_mitsuba_full(sample.definition, body, **kwargs)
    white = mb.render_mitsuba_full(sample.definition, {"type": "diffuse", "reflectance": 1.0}, **kwargs)
    full = rendered.coverage >= 1.0
    lit = white.sphere_part.mean(axis=-1)
    chosen = full & (lit > 0.5 * lit[full].max())
    albedo = np.median(rendered.sphere_part[chosen] / white.sphere_part[chosen], axis=0)
    return [round(float(x), 4) for x in albedo]


def _portable(translation: dict[str, Any], sample: BundledSample) -> dict[str, Any]:
    """The translation as stored: an environment image named as the scene names it
    (relative to the scene folder), not by this machine's absolute path."""
    background = translation.get("background", {})
    if "image" in background:
        background["image"] = sample.definition["background"]["image"]
    return translation


def render_sample(sample: BundledSample, variant: str) -> tuple[dict[str, bytes], dict[str, Any]]:
    """Render one sample: its files' bytes by name and its index entry (nothing written)."""
    results = [
        mb.render_mitsuba_full(
            sample.definition, sample.bsdf, spp=sample.spp, seed=s, variant=variant, base_dir=SCENE_DIR
        )
        for s in sample.seeds
    ]
    image = 0.5 * (results[0].image.astype(np.float64) + results[1].image.astype(np.float64))
    if not np.all(np.isfinite(image)):
        raise mb.MitsubaBackendError(f"{sample.id}: the rendering holds NaN or infinite values")
    coverage = results[0].coverage
    noise = mb.measure_noise(results[0].image, results[1].image, coverage)
    full = coverage >= 1.0
    partial = (coverage > 0) & ~full
    files = sample_files(sample)
    contents: dict[str, bytes] = {}
    contents[files["exr"]] = float_exr_bytes(image, compression=IMAGE_COMPRESSION)
    quantization = (decode_exr(contents[files["exr"]]) - image)[full].std(axis=0)
    contents[files["coverage"]] = float_exr_bytes(coverage, compression=COVERAGE_COMPRESSION, channel_names=("Y",))
    contents[files["mask"]] = mask_bytes(full)
    monte_carlo = np.asarray(noise["of_mean"])
    per_channel = np.sqrt(monte_carlo**2 + quantization**2)

    sidecar = {"format": SIDECAR_FORMAT, "version": 1, **describe(sample, variant)}
    sidecar["render"].update(
        {
            "seeds": list(sample.seeds),
            "mitsuba_version": results[0].version,
            "integrator": "path",
            "max_depth": mb.DEFAULT_MAX_DEPTH,
            "rr_depth": mb.DEFAULT_RR_DEPTH,
            "hide_emitters": True,
            "split_emitters": True,
            "sampler": "stratified",
            "rfilter": "box",
            "seconds": [round(r.seconds, 3) for r in results],
            "translation": _portable(results[0].translation.to_dict(), sample),
        }
    )
    sidecar["noise"] = {
        "per_channel": [float(x) for x in per_channel],
        "relative": [float(x) for x in per_channel / image[full].mean(axis=0)],
        "monte_carlo": [float(x) for x in monte_carlo],
        "quantization": [float(x) for x in quantization],
        "per_render": noise["per_render"],
        "pixels": noise["pixels"],
        "method": NOISE_METHOD,
    }
    sidecar["image"] = {
        "width": int(image.shape[1]),
        "height": int(image.shape[0]),
        "sphere_pixels": int((coverage > 0).sum()),
        "full_pixels": int(full.sum()),
        "partial_pixels": int(partial.sum()),
        "coverage_sum": float(coverage.sum()),
        "max": [float(x) for x in image[full].max(axis=0)],
        "exr": {
            "pixel_type": "float32",
            "compression": IMAGE_COMPRESSION,
            "coverage_compression": COVERAGE_COMPRESSION,
        },
    }
    sidecar["files"] = {role: name for role, name in files.items() if role != "sidecar"}
    albedo = reference_albedo(sample, variant)
    if albedo is not None:
        sidecar["reference"] = {"diffuse_albedo": albedo, "how": REFERENCE_HOW}
    contents[files["sidecar"]] = (json.dumps(sidecar, indent=2, allow_nan=False) + "\n").encode("utf-8")
    entry = {
        "id": sample.id,
        "group": sample.group,
        "model": "mitsuba",
        "scene": sample.scene_name,
        "parameters": sample.bsdf,
        "files": files,
        "sha256": {name: sha256_bytes(data) for name, data in contents.items()},
    }
    return contents, entry


def build_index(samples: Sequence[BundledSample], entries: dict[str, dict[str, Any]], digest: str) -> dict[str, Any]:
    """The ``index.json`` mapping (synth's index format) listing the complete ``entries``."""
    order = [s.id for s in samples]
    return {
        "format": INDEX_FORMAT,
        "version": INDEX_VERSION,
        "spec": SPEC_NAME,
        "description": DESCRIPTION,
        "seed": SEED,
        "plan_sha256": digest,
        "total": len(order),
        "complete": len(entries),
        "pending": [i for i in order if i not in entries],
        "samples": [entries[i] for i in order if i in entries],
    }


def default_variant() -> str:
    """`VARIANT` when it loads, else ``scalar_rgb`` (raises if Mitsuba is missing)."""
    try:
        mb._mitsuba(VARIANT)
        return VARIANT
    except mb.MitsubaUnavailableError:
        mb._mitsuba("scalar_rgb")
        return "scalar_rgb"


def make_bundled(
    output: str | Path = OUTPUT,
    *,
    variant: str | None = None,
    only: Sequence[str] | None = None,
    force: bool = False,
    resume: bool = False,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Render the set (or the samples ``only`` names) into ``output`` and return its index.

    A non-empty folder is refused unless ``force`` (its old dataset's files are removed
    first) or ``resume`` (intact samples of the same plan are kept), as for
    `data_synth.generate`; ``only`` renders the named samples even if they are intact
    and cannot be combined with ``force`` (which would remove the others). Each sample's
    files are written together, then the index."""
    from .generate import prepare_output

    output = Path(output)
    samples = plan()
    known = {s.id for s in samples}
    unknown = sorted(set(only or ()) - known)
    if unknown:
        raise StraussFitError(f"unknown sample id(s) {', '.join(unknown)}; the set has {', '.join(sorted(known))}")
    if only and force:
        raise StraussFitError(
            "--only cannot be combined with --force (that would remove the other samples' files); "
            "use an empty folder, or --resume to keep the others"
        )
    variant = variant or default_variant()
    mb._mitsuba(variant)  # a missing Mitsuba or variant fails before any file is touched
    digest = plan_digest(samples, variant)
    kept = prepare_output(output, digest, force=force, resume=resume)
    entries: dict[str, dict[str, Any]] = {}
    for sample in samples:
        entry = kept.get(sample.id)
        if entry is not None and all(
            (output / name).is_file() and sha256_bytes((output / name).read_bytes()) == value
            for name, value in entry.get("sha256", {}).items()
        ):
            entries[sample.id] = entry
    write_index(output, build_index(samples, entries, digest))
    wanted = [s for s in samples if s.id in only] if only else [s for s in samples if s.id not in entries]
    for n, sample in enumerate(wanted, start=1):
        start = time.perf_counter()
        if entries.pop(sample.id, None) is not None:  # its files are replaced: not complete meanwhile
            write_index(output, build_index(samples, entries, digest))
        contents, entry = render_sample(sample, variant)
        with Outputs(force=True) as out:  # the sample's files, all or none
            for name, data in contents.items():
                out.add_bytes(output / name, data)
            out.commit()
        entries[sample.id] = entry
        write_index(output, build_index(samples, entries, digest))
        if progress:
            progress(f"[{n}/{len(wanted)}] {sample.id} ({time.perf_counter() - start:.1f} s, {variant})")
    return build_index(samples, entries, digest)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m data_synth.make_bundled_mitsuba",
        description="Regenerate the bundled Mitsuba 3 targets (data_synth/bundled_mitsuba).",
    )
    parser.add_argument("--out", "-o", type=Path, default=OUTPUT, help=f"output folder (default: {OUTPUT})")
    parser.add_argument(
        "--variant", choices=mb.VARIANTS, help=f"Mitsuba variant (default: {VARIANT} if it loads, else scalar_rgb)"
    )
    parser.add_argument("--only", nargs="+", metavar="ID", help="render only these samples")
    parser.add_argument("--force", action="store_true", help="replace the dataset in a non-empty output folder")
    parser.add_argument("--resume", action="store_true", help="keep the intact samples of an interrupted run")
    args = parser.parse_args(argv)
    try:
        index = make_bundled(
            args.out,
            variant=args.variant,
            only=args.only,
            force=args.force,
            resume=args.resume,
            progress=lambda line: print(line, file=sys.stderr, flush=True),
        )
    except StraussFitError as exc:
        print(f"make_bundled_mitsuba: error: {exc}", file=sys.stderr)
        return 2
    print(f"{index['complete']} of {index['total']} samples complete in {args.out / INDEX_NAME}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

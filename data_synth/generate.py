"""Generating a dataset: render every planned sample, pass it through the sensor, write its
files, and keep the index up to date.

Per sample, in this order, each file written atomically (temporary file, then rename):

1. the images: ``ID.exr`` (linear float32) and/or ``ID.png`` (8-bit sRGB) with
   ``ID.clip.png`` (255 where the PNG is clipped);
2. the sidecar ``ID.json`` (model, exact parameters, scene, sensor, seed, files);
3. the index ``index.json``, rewritten to list the sample (with the SHA-256 of its files).

A sample is complete exactly when the index lists it. An interruption or a failed write
(a full disk) at any point leaves the index listing only complete samples; files of the
sample in progress may remain and are overwritten when the run is resumed. Resuming skips
every listed sample whose files still exist with the recorded checksums and renders the
rest; since every sample has its own seed (:mod:`data_synth.plan`), the result is
byte-identical to an uninterrupted run.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from strauss_fit.errors import ImageError, OutputExistsError, StraussFitError

from .files import sha256, write_codes, write_exr, write_mask
from .index import INDEX_NAME, build_index, read_index, write_index
from .params import MODELS, SpecError
from .plan import SamplePlan, describe, noise_rng, plan_digest, plan_samples
from .spec import DatasetSpec

SIDECAR_FORMAT = "strauss-fit synth sample"
FORMAT_VERSION = 1


class GenerationError(StraussFitError):
    """Writing the dataset failed (e.g. a full disk); the index lists what is complete."""


@dataclass(frozen=True)
class Progress:
    """Reported after each sample written: ``done`` of ``total`` samples are complete;
    ``seconds`` it took to render and write."""

    done: int
    total: int
    sample_id: str
    seconds: float


@dataclass(frozen=True)
class Report:
    """The outcome of :func:`generate`."""

    output: Path
    total: int
    complete: int
    written: int
    skipped: int

    @property
    def finished(self) -> bool:
        return self.complete == self.total


def render_model(model: str, scene: Any, material: Any) -> tuple[np.ndarray, np.ndarray]:
    """Render ``scene`` with a material of ``model`` (``"strauss"``: the full renderer,
    global model included; ``"phong"``: the local Phong model): the linear radiance
    (H, W, 3) float64 and the sphere mask (H, W), as numpy arrays."""
    from strauss_fit.render.phong import render_phong
    from strauss_fit.render.strauss import render

    if model == "phong":
        image, mask = render_phong(scene, material)
    else:
        image, mask = render(scene, material)
    return np.asarray(image, dtype=np.float64), np.asarray(mask)


def render_clean(sample: SamplePlan) -> tuple[np.ndarray, np.ndarray]:
    """The noise-free linear radiance (H, W, 3) float64 and the sphere mask of a sample."""
    material = MODELS[sample.model].make_material(dict(sample.parameters))
    return render_model(sample.model, sample.scene.scene, material)


def sample_files(sample: SamplePlan) -> dict[str, str]:
    """The file names of a sample, by role: ``exr``, ``png``, ``clip_mask``, ``sidecar``."""
    files = {}
    if "exr" in sample.group.formats:
        files["exr"] = f"{sample.id}.exr"
    if "png" in sample.group.formats:
        files["png"] = f"{sample.id}.png"
        files["clip_mask"] = f"{sample.id}.clip.png"
    files["sidecar"] = f"{sample.id}.json"
    return files


class _WriteFailed(Exception):
    """A file of the dataset could not be written (the reason is one line)."""


def write_sample(spec: DatasetSpec, sample: SamplePlan, output: Path) -> dict[str, Any]:
    """Render and write one sample's images and sidecar; return its index entry."""
    from strauss_fit.io.files import write_json

    from .sensor import encode_ldr

    clean, sphere = render_clean(sample)
    observed = sample.group.sensor.apply(clean, noise_rng(spec, sample))
    files = sample_files(sample)
    sidecar = {"format": SIDECAR_FORMAT, "version": FORMAT_VERSION, **describe(spec, sample)}
    sidecar["image"] = {"width": int(clean.shape[1]), "height": int(clean.shape[0]), "sphere_pixels": int(sphere.sum())}
    try:
        if "exr" in files:
            write_exr(output / files["exr"], observed, force=True)
        if "png" in files:
            codes, clipped = encode_ldr(observed)
            write_codes(output / files["png"], codes, force=True)
            write_mask(output / files["clip_mask"], clipped, force=True)
            sidecar["image"]["clipped_pixels"] = int(clipped.sum())
        sidecar["files"] = {k: v for k, v in files.items() if k != "sidecar"}
        write_json(output / files["sidecar"], sidecar, force=True)
        checksums = {name: sha256(output / name) for name in files.values()}
    except OSError as exc:
        raise _WriteFailed(exc.strerror or str(exc)) from None
    except ImageError as exc:
        raise _WriteFailed(str(exc)) from None
    return {
        "id": sample.id,
        "group": sample.group.name,
        "model": sample.model,
        "scene": sample.scene.name,
        "parameters": sample.parameters,
        "files": files,
        "sha256": checksums,
    }


def _is_intact(entry: dict[str, Any], output: Path) -> bool:
    try:
        return all(
            (output / name).is_file() and sha256(output / name) == digest for name, digest in entry["sha256"].items()
        )
    except (KeyError, AttributeError, TypeError, OSError):
        return False


def prepare_output(output: Path, digest: str, *, force: bool, resume: bool) -> dict[str, dict[str, Any]]:
    """Check or create the output folder; return the complete entries to keep (resume)."""
    if force and resume:
        raise StraussFitError("--force and --resume exclude each other")
    if output.exists() and not output.is_dir():
        raise OutputExistsError(f"output {output} exists and is not a folder")
    if not output.exists():
        parent = output.parent if str(output.parent) else Path(".")
        if not parent.is_dir():
            raise StraussFitError(f"output folder's parent does not exist: {parent}")
        output.mkdir()
        return {}
    index_path = output / INDEX_NAME
    if not any(output.iterdir()):
        return {}
    if resume:
        if not index_path.is_file():
            raise OutputExistsError(f"cannot resume: {output} has no {INDEX_NAME} (not a dataset folder)")
        index = read_index(output)
        if index.get("plan_sha256") != digest:
            raise OutputExistsError(
                f"cannot resume: {output} holds a dataset from another spec or seed; pass --force to replace it"
            )
        return {e["id"]: e for e in index.get("samples", []) if isinstance(e, dict) and "id" in e}
    if not force:
        raise OutputExistsError(
            f"output folder {output} is not empty; pass --resume to continue the dataset in it or --force to replace it"
        )
    if index_path.is_file():  # replace the old dataset: remove exactly the files it lists
        try:
            old = read_index(output)
        except StraussFitError:
            old = {}  # an unreadable index lists nothing; it is overwritten below
        for entry in old.get("samples", []):
            for name in (entry.get("files") or {}).values() if isinstance(entry, dict) else ():
                if isinstance(name, str) and "/" not in name and "\\" not in name:
                    (output / name).unlink(missing_ok=True)
        index_path.unlink()
    return {}


def generate(
    spec: DatasetSpec,
    output: str | Path,
    *,
    force: bool = False,
    resume: bool = False,
    limit: int | None = None,
    progress: Callable[[Progress], None] | None = None,
) -> Report:
    """Generate (or resume) the dataset of ``spec`` in the folder ``output``.

    An existing non-empty folder is refused unless ``resume`` (continue the same dataset:
    same spec, same seed) or ``force`` (replace it: the files of the old index are removed,
    others are left alone). ``limit`` caps the number of samples written by this call.
    ``progress`` is called after every sample. Returns a :class:`Report`; raises
    :class:`GenerationError` (one line, naming how many samples are complete) if a write
    fails, and lets ``KeyboardInterrupt`` through: in both cases the index lists exactly
    the complete samples.
    """
    output = Path(output)
    if limit is not None and limit < 1:
        raise SpecError(f"limit must be at least 1, got {limit}")
    samples = plan_samples(spec)
    digest = plan_digest(spec, samples)
    kept = prepare_output(output, digest, force=force, resume=resume)
    entries: dict[str, dict[str, Any]] = {}
    order = [s.id for s in samples]

    def save() -> None:
        try:
            write_index(output, build_index(spec, digest, order, entries))
        except OSError as exc:
            raise _WriteFailed(exc.strerror or str(exc)) from None

    for sample in samples:  # keep what is intact, forget what is not
        entry = kept.get(sample.id)
        if entry is not None and _is_intact(entry, output):
            entries[sample.id] = entry
    skipped = len(entries)
    written = 0
    try:
        save()
        for sample in samples:
            if sample.id in entries:
                continue
            if limit is not None and written >= limit:
                break
            start = time.perf_counter()
            entries[sample.id] = write_sample(spec, sample, output)
            save()
            written += 1
            if progress:
                progress(Progress(len(entries), len(samples), sample.id, time.perf_counter() - start))
    except _WriteFailed as exc:
        raise GenerationError(
            f"writing {output} failed ({exc}); {_complete(output)} of {len(samples)} samples are complete "
            f"and listed in {output / INDEX_NAME}; rerun with --resume"
        ) from None
    return Report(output, len(samples), len(entries), written, skipped)


def _complete(output: Path) -> int:
    """How many samples the index on disk lists (0 if it cannot be read)."""
    try:
        return len(read_index(output).get("samples", []))
    except (StraussFitError, OSError):
        return 0

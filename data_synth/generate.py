"""Generating a dataset: render every planned sample, pass it through the sensor, write its
files, and keep the index up to date.

Per sample, in this order:

1. the images are rendered and encoded in memory: ``ID.exr`` (linear float32) and/or
   ``ID.png`` (8-bit sRGB) with ``ID.clip.png`` (255 where the PNG is clipped), and the
   sidecar ``ID.json`` (model, exact parameters, scene, sensor, seed, files);
2. the files are written to temporary files, every write checked, then renamed into place
   together (`strauss_fit.io.files.Outputs`);
3. the index ``index.json`` is rewritten (atomically) to list the sample (with the SHA-256
   of its files).

A sample is complete exactly when the index lists it. An interruption or a failed write
(a full disk) at any point leaves the index listing only complete samples and no file of
the sample in progress (if the index cannot be updated, the sample's files just written
are removed again); the run stops (a full disk stops every later sample too)
and says how many samples are complete. A sample that cannot be made — its scene is not
usable (an environment map holding NaN), its rendering is not finite — is reported, its
files are not written and the batch goes on; the run then ends with
`Report.failed` listing them (the command exits with status 1). Resuming skips every
listed sample whose files still exist with the recorded checksums and renders the rest
(failed samples are tried again); since every sample has its own seed
(`data_synth.plan`), the result is byte-identical to an uninterrupted run.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from strauss_fit.errors import OutputExistsError, StraussFitError
from strauss_fit.io.files import Outputs, WriteError

from .files import codes_bytes, exr_bytes, mask_bytes, sha256, sha256_bytes
from .index import INDEX_NAME, build_index, read_index, write_index
from .params import MODELS, REFLECTANCE_SYNTH_MODELS, SpecError
from .plan import SamplePlan, describe, noise_rng, plan_digest, plan_samples
from .spec import DatasetSpec

SIDECAR_FORMAT = "strauss-fit synth sample"
FORMAT_VERSION = 1


class GenerationError(StraussFitError):
    """Writing the dataset failed (e.g. a full disk); the index lists what is complete."""


class SampleFailed(StraussFitError):
    """One sample cannot be made (its scene is unusable, its rendering is not finite)."""


@dataclass(frozen=True)
class Progress:
    """Reported after each sample written or failed: ``done`` of ``total`` samples are
    complete; ``seconds`` it took to render and write; ``error`` why it failed, if it did."""

    done: int
    total: int
    sample_id: str
    seconds: float
    error: str | None = None


@dataclass(frozen=True)
class Report:
    """The outcome of `generate`."""

    output: Path
    total: int
    complete: int
    written: int
    skipped: int
    failed: tuple[tuple[str, str], ...] = ()

    @property
    def finished(self) -> bool:
        return self.complete == self.total

    @property
    def stopped_by_limit(self) -> bool:
        """Whether samples are left that this run did not try (``limit``)."""
        return self.complete + len(self.failed) < self.total


def _render_strauss(scene: Any, material: Any) -> tuple[Any, Any]:
    from strauss_fit.rendering.strauss import render

    return render(scene, material)


def _render_phong(scene: Any, material: Any) -> tuple[Any, Any]:
    from strauss_fit.rendering.phong import render_phong

    return render_phong(scene, material)


def _reflectance_renderer(name: str) -> Callable[[Any, Any], tuple[Any, Any]]:
    """The renderer of the registry model ``name``: its material is the values dict."""

    def render(scene: Any, values: Any) -> tuple[Any, Any]:
        from strauss_fit.rendering.reflectance import render_model as render_reflectance

        return render_reflectance(scene, name, values)

    return render


#: Every model's renderer by name (as colour-science's ``*_METHODS``): the classic ones
#: (`CLASSIC_MODELS`), then every registry model synth offers.
RENDER_METHODS: MappingProxyType[str, Callable[[Any, Any], tuple[Any, Any]]] = MappingProxyType(
    {
        "strauss": _render_strauss,
        "phong": _render_phong,
        **{name: _reflectance_renderer(name) for name in REFLECTANCE_SYNTH_MODELS},
    }
)


def render_model(model: str, scene: Any, material: Any) -> tuple[np.ndarray, np.ndarray]:
    """Render ``scene`` with a material of ``model`` (``"strauss"``: the full renderer,
    global model included; ``"phong"``: the local classic Phong model; any other name of
    `MODELS`: that registry model, local and opaque, its material
    the values dict): the linear radiance (H, W, 3) float64 and the sphere mask (H, W), as
    numpy arrays."""
    try:
        renderer = RENDER_METHODS[model]
    except (KeyError, TypeError):
        raise SpecError(f"unknown model {model!r}; expected one of {', '.join(RENDER_METHODS)}") from None
    image, mask = renderer(scene, material)
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
    """Render and write one sample's images and sidecar (all or none); return its index
    entry. Raises `SampleFailed` if the sample cannot be made and ``_WriteFailed``
    if its files cannot be written."""
    import json

    from .sensor import encode_ldr

    if sample.scene.error is not None:
        raise SampleFailed(f"its scene cannot be used: {sample.scene.error}")
    try:
        clean, sphere = render_clean(sample)
        if not np.all(np.isfinite(clean)):
            raise SampleFailed(f"the rendering holds {int(np.sum(~np.isfinite(clean)))} NaN or infinite value(s)")
        observed = sample.group.sensor.apply(clean, noise_rng(spec, sample))
        files = sample_files(sample)
        sidecar = {"format": SIDECAR_FORMAT, "version": FORMAT_VERSION, **describe(spec, sample)}
        sidecar["image"] = {
            "width": int(clean.shape[1]),
            "height": int(clean.shape[0]),
            "sphere_pixels": int(sphere.sum()),
        }
        contents: dict[str, bytes] = {}
        if "exr" in files:
            contents[files["exr"]] = exr_bytes(observed)
        if "png" in files:
            codes, clipped = encode_ldr(observed)
            contents[files["png"]] = codes_bytes(codes)
            contents[files["clip_mask"]] = mask_bytes(clipped)
            sidecar["image"]["clipped_pixels"] = int(clipped.sum())
        sidecar["files"] = {k: v for k, v in files.items() if k != "sidecar"}
        contents[files["sidecar"]] = (json.dumps(sidecar, indent=2, allow_nan=False) + "\n").encode("utf-8")
    except SampleFailed:
        raise
    except (StraussFitError, ValueError) as exc:  # a value the sample cannot hold (NaN in a sidecar, ...)
        raise SampleFailed(str(exc).splitlines()[0] if str(exc) else type(exc).__name__) from None
    try:
        with Outputs(force=True) as out:  # all files of the sample, or none
            for name, data in contents.items():
                out.add_bytes(output / name, data)
            out.commit()
    except WriteError as exc:
        raise _WriteFailed(str(exc)) from None
    return {
        "id": sample.id,
        "group": sample.group.name,
        "model": sample.model,
        "scene": sample.scene.name,
        "parameters": sample.parameters,
        "files": files,
        "sha256": {name: sha256_bytes(data) for name, data in contents.items()},
    }


def unusable_scenes(spec: DatasetSpec) -> list[tuple[str, str, int]]:
    """The scenes whose samples will fail: (group, error, number of samples)."""
    samples = plan_samples(spec)
    out = []
    for group in spec.groups:
        for ref in group.scenes:
            if ref.error is not None:
                count = sum(1 for s in samples if s.group is group and s.scene is ref)
                out.append((group.name, ref.error, count))
    return out


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
    ``progress`` is called after every sample. A sample that cannot be made is skipped and
    listed in `Report.failed`. Returns a `Report`; raises
    `GenerationError` (one line, naming how many samples are complete) if a write
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
        except (OSError, WriteError) as exc:
            raise _WriteFailed(str(exc) if isinstance(exc, WriteError) else (exc.strerror or str(exc))) from None

    for sample in samples:  # keep what is intact, forget what is not
        entry = kept.get(sample.id)
        if entry is not None and _is_intact(entry, output):
            entries[sample.id] = entry
    skipped = len(entries)
    written = 0
    failed: list[tuple[str, str]] = []
    try:
        save()
        for sample in samples:
            if sample.id in entries:
                continue
            if limit is not None and written >= limit:
                break
            start = time.perf_counter()
            try:
                entries[sample.id] = write_sample(spec, sample, output)
            except SampleFailed as exc:  # one bad sample never stops the others
                failed.append((sample.id, str(exc)))
                if progress:
                    progress(Progress(len(entries), len(samples), sample.id, time.perf_counter() - start, str(exc)))
                continue
            try:
                save()
            except _WriteFailed:  # the index cannot list it: its files go too (only listed samples remain)
                for name in entries.pop(sample.id)["files"].values():
                    (output / name).unlink(missing_ok=True)
                raise
            written += 1
            if progress:
                progress(Progress(len(entries), len(samples), sample.id, time.perf_counter() - start))
    except _WriteFailed as exc:
        raise GenerationError(
            f"writing {output} failed ({exc}); {_complete(output)} of {len(samples)} samples are complete "
            f"and listed in {output / INDEX_NAME}; rerun with --resume"
        ) from None
    return Report(output, len(samples), len(entries), written, skipped, tuple(failed))


def _complete(output: Path) -> int:
    """How many samples the index on disk lists (0 if it cannot be read)."""
    try:
        return len(read_index(output).get("samples", []))
    except (StraussFitError, OSError):
        return 0

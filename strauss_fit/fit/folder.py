r"""Many targets into one folder of results: what ``strauss-fit fit T1 T2 … -o OUTDIR`` does.

For each target, ``OUTDIR/<target's file stem>.json`` (the fit result, as the single fit
writes it) and, on request, ``OUTDIR/<stem>.compare.png`` are written together as soon as
the target is fitted; at the end ``OUTDIR/summary.csv`` (one row per target, in input
order, :data:`~strauss_fit.fit.summary.SUMMARY_COLUMNS`) is rewritten. So a run that is
killed loses only the targets in flight, and ``resume`` skips every target whose result is
already there (a complete JSON result of the same target) and fits the rest, the failed
ones included. A target that fails is a row with ``status`` "failed" and its one-line
error; the others go on.

The rules that keep a folder's results honest, all checked before any work:

- **An output never names an input.** A result (``<stem>.json``), a comparison image or
  ``summary.csv`` that would be a target, a scene, a mask, a manifest, a target list, or a
  target's sidecar (``<stem>.json`` beside ``<stem>.exr``, which holds its noise and truth)
  is refused whatever ``--force`` or ``--resume`` say: fit into another folder.
- **A result is kept only for the run that made it.** Every result records its
  ``provenance``: digests of the target's bytes, the scene, the mask and the settings, and
  the key made of them with strauss-fit's version (:func:`~strauss_fit.io.journal.run_key`).
  ``resume`` keeps a result whose key is this run's; a result of another configuration (or
  one without a key) is refused with what differs, never silently kept; a result missing its
  core keys (:data:`CORE_KEYS`: hand-edited, say) is incomplete and fitted again, as is a
  kept result without the comparison image ``compare`` asks for.
- **Outputs go where files may go.** A folder, a device or a FIFO at an output's path is
  refused (:func:`~strauss_fit.io.files.check_replaceable`), ``force`` or not.
- **Each target once.** The same target given twice, and two targets whose results would
  share a name, are refused.
- The folder itself is created only once the work has started (the cluster reached, the
  first result in), so a run that cannot start leaves nothing behind.

Targets can be files, folders (their images: every file OpenImageIO reads, sorted), lists
(``@list.txt``: one path per line, ``#`` comments) or a manifest (CSV or JSON) that pairs
each target with its own scene, mask and encoding.

What every target shares — the ``--scene`` and ``--mask`` of the command line — is read
before any work (:func:`jobs_from_arguments`): a missing or broken one would fail every
target, so it is bad input (one line, exit status 2), as with a single target. What
belongs to one target — the image, a manifest row's own scene or mask — fails that target
alone.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import OutputExistsError, StraussFitError
from ..inference.noise import sidecar_path
from ..io.files import Outputs, check_input_file, check_replaceable, read_json
from ..io.images import read_image
from ..io.journal import file_digest, pytree_digest, run_key
from ..io.targets import Target
from ..scene.loading import load_scene
from .batch import DEFAULT_CHUNK, BatchProgress, FitFailure, FitJob, fit_many
from .options import FitOptions
from .result import FitResult
from .summary import SUMMARY_COLUMNS, comparison_image, standardized_map, summary_row

#: File endings taken as images when a folder is given.
IMAGE_SUFFIXES = (".exr", ".hdr", ".tif", ".tiff", ".pfm", ".png", ".jpg", ".jpeg", ".bmp", ".tga")
SUMMARY_NAME = "summary.csv"
#: Manifest columns: the target and, optionally, its own scene, mask and encoding.
MANIFEST_COLUMNS = ("target", "scene", "mask", "encoding")


def expand_targets(arguments: Sequence[str]) -> list[Path]:
    """Image paths from the command line's TARGET arguments: files as given, folders as
    their images (sorted; files that are not images, the ``.compare.png`` of a result
    folder and clip masks are skipped), ``@LIST`` as the paths in LIST (one per line,
    relative to LIST's folder, ``#`` comments)."""
    out: list[Path] = []
    for argument in arguments:
        if argument.startswith("@"):
            listing = check_input_file(argument[1:], "target list")
            try:
                lines = listing.read_text(encoding="utf-8").splitlines()
            except (OSError, UnicodeDecodeError) as exc:
                raise StraussFitError(f"cannot read the target list {listing}: {exc}") from None
            for line in lines:
                line = line.split("#", 1)[0].strip()
                if line:
                    path = Path(line)
                    out.append(path if path.is_absolute() else listing.parent / path)
            continue
        path = Path(argument)
        if path.is_dir():
            found = sorted(
                p
                for p in path.iterdir()
                if p.is_file()
                and p.suffix.lower() in IMAGE_SUFFIXES
                and not p.name.endswith((".compare.png", ".clip.png", ".mask.png", ".coverage.exr"))
            )
            if not found:
                raise StraussFitError(f"the folder {path} holds no image")
            out.extend(found)
        else:
            out.append(path)
    if not out:
        raise StraussFitError("no target to fit")
    return out


def read_manifest(path: str | Path, default_scene: str | Path | None) -> list[dict[str, str]]:
    """The rows of a CSV or JSON manifest (columns :data:`MANIFEST_COLUMNS`; paths relative
    to the manifest's folder); a row without a scene takes ``default_scene``."""
    path = check_input_file(path, "manifest")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise StraussFitError(f"cannot read the manifest {path}: {exc}") from None
    if path.suffix.lower() == ".json":
        rows = read_json(path, "manifest")
        if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
            raise StraussFitError(f"the manifest {path} must be a JSON list of objects")
    else:
        rows = list(csv.DictReader(io.StringIO(text)))
    if not rows:
        raise StraussFitError(f"the manifest {path} lists no target")
    out = []
    for number, row in enumerate(rows, start=1):
        unknown = set(row) - set(MANIFEST_COLUMNS)
        if unknown:
            raise StraussFitError(
                f"{path}, row {number}: unknown column(s) {', '.join(sorted(map(str, unknown)))}; "
                f"known: {', '.join(MANIFEST_COLUMNS)}"
            )
        if not row.get("target"):
            raise StraussFitError(f"{path}, row {number}: no target")
        entry = {}
        for key in ("target", "scene", "mask"):
            value = row.get(key) or (default_scene if key == "scene" else None)
            if value:
                value_path = Path(str(value))
                keep = value_path.is_absolute() or (key == "scene" and value == default_scene)
                entry[key] = str(value_path if keep else path.parent / value_path)
        if "scene" not in entry:
            raise StraussFitError(f"{path}, row {number}: no scene (give a scene column or --scene)")
        entry["encoding"] = str(row.get("encoding") or "auto")
        if entry["encoding"] not in ("auto", "linear", "srgb"):
            raise StraussFitError(f"{path}, row {number}: encoding must be auto, linear or srgb")
        out.append(entry)
    return out


def result_names(targets: Sequence[str | Path]) -> list[str]:
    """The result file stem of every target: its file stem. The same target given twice
    (by any path to the same file) and targets whose stems collide are refused: one result
    would overwrite the other."""
    stems = [Path(t).stem for t in targets]
    seen: dict[str, str] = {}
    files: dict[str, str] = {}
    for stem, target in zip(stems, targets):
        identity = _identity(target)
        if identity in files:
            same = "" if files[identity] == str(target) else f" (as {files[identity]} and {target})"
            raise StraussFitError(f"the target {target} is given twice{same}: give each target once")
        files[identity] = str(target)
        if stem in seen:
            raise StraussFitError(
                f"two targets would write the same result {stem}.json: {seen[stem]} and {target}; rename one, "
                "or fit them into different folders"
            )
        seen[stem] = str(target)
    return stems


def _identity(path: str | Path) -> tuple:
    """What makes two paths the same file: device and inode where it exists (hard and
    symbolic links included), else the resolved path."""
    try:
        status = os.stat(path)
        return (status.st_dev, status.st_ino)
    except OSError:
        return (os.path.normcase(os.path.realpath(path)),)


def sidecar_of(target: str | Path) -> Path | None:
    """The target's sidecar, if one exists: ``<stem>.json`` beside the image (a synthetic
    dataset's noise and truth, see docs/datasets.md), unless that file is itself a fit
    result (a result fitted into the target's own folder earlier). An output must never
    replace it."""
    candidate = sidecar_path(target)
    if Path(target).suffix.lower() == ".json" or not candidate.is_file():
        return None
    try:
        FitResult.from_json(json.loads(candidate.read_text(encoding="utf-8")))
        return None
    except Exception:
        return candidate


def check_outputs_are_not_inputs(
    outputs: Sequence[Path], jobs: Sequence[FitJob], inputs: Sequence[str | Path] = ()
) -> None:
    """Refuse, before any work, an output that is one of the run's inputs: a target, its
    sidecar (:func:`sidecar_of`), a scene, a mask, or one of ``inputs`` (the manifest,
    target lists). ``--force`` does not change this: fit into another folder."""
    named: dict[tuple, str] = {}
    for path in inputs:
        named.setdefault(_identity(path), f"the input {path}")
    for job in jobs:
        for what, path in (("target", job.target), ("scene", job.scene), ("mask", job.mask)):
            if isinstance(path, (str, Path)):
                named.setdefault(_identity(path), f"the {what} {path}")
        if isinstance(job.target, (str, Path)):
            sidecar = sidecar_of(job.target)
            if sidecar is not None:
                named.setdefault(_identity(sidecar), f"the sidecar of the target {job.target} (its noise and truth)")
    for output in outputs:
        clash = named.get(_identity(output))
        if clash is not None:
            raise StraussFitError(
                f"the output {output} would overwrite {clash}: an output never replaces an input; fit into another "
                "folder (-o)"
            )


#: What a complete result holds besides the material and ``free``: a result without one of
#: these (hand-edited, say) is incomplete, and ``resume`` fits its target again.
#: Each maps to its fields and their types (a ± for every free parameter is checked too).
CORE_KEYS: dict[str, dict[str, tuple[type, ...]]] = {
    "residual": {"rms": (int, float), "sum_of_squares": (int, float)},
    "solver": {"status": (str,)},
    "uncertainty": {},
    "settings": {},
}


def provenance(job: FitJob) -> dict[str, Any] | None:
    """What decides a target's result, as digests (``target_sha256`` of the image's bytes,
    ``scene_sha256``, ``mask_sha256``, ``settings_sha256`` of the options and encoding),
    strauss-fit's version, and ``key``, the run key of them all. None when an input cannot
    be read (the fit then fails on it and says why)."""

    def digest(value: Any) -> str | None:
        if value is None:
            return None
        if isinstance(value, (str, Path)):
            return file_digest(check_input_file(value))
        if isinstance(value, Target):
            return pytree_digest((value.pixels, value.usable))
        return pytree_digest(value)

    from .._version import __version__

    try:
        parts = {
            "target_sha256": digest(job.target),
            "scene_sha256": digest(job.scene),
            "mask_sha256": digest(job.mask),
        }
    except (OSError, StraussFitError):
        return None
    settings = json.dumps({"options": job.options.as_dict(), "encoding": job.encoding}, sort_keys=True, default=str)
    parts["settings_sha256"] = hashlib.sha256(settings.encode("utf-8")).hexdigest()
    return {**parts, "strauss_fit": __version__, "key": run_key(parts)}


#: Names of the provenance digests, as a user reads them in a refusal.
_PROVENANCE_NAMES = {
    "target_sha256": "the target's bytes",
    "scene_sha256": "the scene",
    "mask_sha256": "the mask",
    "settings_sha256": "the settings",
    "strauss_fit": "the strauss-fit version",
}


@dataclass
class FolderRun:
    """What :func:`fit_to_folder` did: per target (input order) its summary row; counts."""

    rows: list[dict[str, Any]]
    fitted: int
    skipped: int
    failed: int
    summary: Path


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _complete(data: dict[str, Any]) -> bool:
    """Whether a result holds every core key (:data:`CORE_KEYS`) with numbers where numbers
    belong, and a deviation for every free parameter."""
    for key, fields in CORE_KEYS.items():
        part = data.get(key)
        if not isinstance(part, dict):
            return False
        for field, kinds in fields.items():
            value = part.get(field)
            if not isinstance(value, kinds) or isinstance(value, bool):
                return False
    uncertainty = data["uncertainty"]
    for name in data.get("free") or []:
        value = uncertainty.get(name)
        values = value if isinstance(value, list) else [value]
        if not values or not all(_is_number(v) for v in values):
            return False
    return True


def _kept(path: Path, expected: dict[str, Any] | None) -> tuple[dict[str, Any] | None, str | None]:
    """What ``resume`` does with the result at ``path``: ``(data, None)`` keeps it (complete,
    and of this run: same provenance key); ``(None, None)`` fits the target again (no result
    there, or an incomplete one); ``(None, reason)`` refuses the run (a complete result of
    another configuration, or one without provenance)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        FitResult.from_json(data)
    except Exception:
        return None, None  # not a result (a half-edited file): nothing to keep
    if not _complete(data):
        return None, None
    recorded = data.get("provenance")
    if not isinstance(recorded, dict) or "key" not in recorded:
        return None, "it records no provenance (an older strauss-fit wrote it, or it was edited)"
    if expected is None or recorded.get("key") != expected["key"]:
        differ = [
            name for key, name in _PROVENANCE_NAMES.items() if expected and recorded.get(key) != expected.get(key)
        ]
        which = ", ".join(differ) or "its key"
        return None, f"it was fitted with other inputs or options (different: {which})"
    return data, None


def fit_to_folder(
    jobs: Sequence[FitJob],
    folder: str | Path,
    *,
    executor: Any = None,
    chunk_size: int = DEFAULT_CHUNK,
    resume: bool = False,
    force: bool = False,
    compare: bool = False,
    recorded: Callable[[FitJob], dict[str, Any]] | None = None,
    progress: Callable[[BatchProgress], None] | None = None,
    on_result: Callable[[int, FitResult | FitFailure], None] | None = None,
    inputs: Sequence[str | Path] = (),
    log: Callable[[str], None] | None = None,
) -> FolderRun:
    """Fit ``jobs`` into ``folder`` (see the module docstring for the rules). ``recorded(job)``
    gives the extra keys each result JSON records (the command line's target, scene, mask,
    encoding, quality); ``inputs`` names further input files no output may replace (a
    manifest, target lists); ``log`` receives a line about results fitted again. Existing
    results are refused unless ``resume`` (keep those of this run, fit the rest) or
    ``force`` (fit everything again), all before any work."""
    folder = Path(folder)
    if resume and force:
        raise StraussFitError("give --resume or --force, not both")
    if folder.exists() and not folder.is_dir():
        raise StraussFitError(f"the output {folder} is a file; several targets need an output folder")
    if not folder.exists():
        if not folder.parent.is_dir():
            raise StraussFitError(f"the output folder's parent does not exist: {folder.parent}")
        if not os.access(folder.parent, os.W_OK):
            raise StraussFitError(f"cannot create the output folder {folder}: {folder.parent} is not writable")
    names = result_names([job.name for job in jobs])
    paths = [folder / f"{name}.json" for name in names]
    summary = folder / SUMMARY_NAME
    outputs = [*paths, summary, *([folder / f"{name}.compare.png" for name in names] if compare else [])]
    check_outputs_are_not_inputs(outputs, jobs, inputs)
    for output in outputs:  # a folder or a device where a result must go: refused, whatever the flags
        check_replaceable(output)
    if not (resume or force):
        # results are the targets' JSON files; summary.csv is not one, but would be replaced
        existing = [p for p in paths if p.exists()]
        if existing:
            raise OutputExistsError(
                f"{len(existing)} result(s) already in {folder} (e.g. {existing[0].name}); pass --resume to keep "
                "them and fit the rest, or --force to fit everything again"
            )
        if summary.exists():
            raise OutputExistsError(
                f"{folder} already holds a {SUMMARY_NAME} from an earlier run; pass --resume to keep its results "
                "and fit the rest, or --force to replace it"
            )
    keys = [provenance(job) for job in jobs]
    rows: list[dict[str, Any] | None] = [None] * len(jobs)
    todo, incomplete, uncompared = [], 0, 0
    for index, (job, path) in enumerate(zip(jobs, paths)):
        done, refused = _kept(path, keys[index]) if resume and path.exists() else (None, None)
        if refused is not None:
            raise OutputExistsError(
                f"{path} is not a result of this run: {refused}; resuming would mix two configurations: pass "
                "--force to fit every target again with this one, or fit into another folder"
            )
        if done is not None and compare and not (folder / f"{names[index]}.compare.png").is_file():
            done, uncompared = None, uncompared + 1  # its comparison image needs the fit's images: fit again
        elif done is None:
            incomplete += resume and path.exists()
        if done is not None:
            rows[index] = summary_row(job.name, done, path=path.name)
        else:
            todo.append(index)
    if log is not None and incomplete:
        log(
            f"{incomplete} incomplete result(s) in {folder} (missing {', '.join(CORE_KEYS)} or their figures): "
            "fitted again"
        )
    if log is not None and uncompared:
        log(f"{uncompared} kept result(s) have no comparison image for --compare: fitted again to draw it")
    if resume and folder.is_dir():  # a killed run's half-written temporaries of these results
        for name in names:
            for stale in folder.glob(f".{name}.*.tmp*"):
                stale.unlink(missing_ok=True)
    counts = {"failed": 0}

    def arrived(position: int, result: FitResult | FitFailure) -> None:
        index = todo[position]
        job, path = jobs[index], paths[index]
        if isinstance(result, FitFailure):
            rows[index] = summary_row(job.name, None, error=result.message)
            counts["failed"] += 1
        else:
            payload = result.to_json()
            for key, value in (recorded(job) if recorded else {}).items():
                if isinstance(value, dict) and isinstance(payload.get(key), dict):
                    payload[key].update(value)  # e.g. settings: the quality preset's name
                else:
                    payload[key] = value
            if keys[index] is not None:
                payload["provenance"] = keys[index]
            _create(folder)
            with Outputs(force=True) as out:  # this target's files together
                out.add_json(path, payload)
                if compare and result.fitted_image is not None and result.target_image is not None:
                    target = result.target_image
                    image = comparison_image(
                        target, result.fitted_image, result.mask, standardized_map(result, target.shape[:2])
                    )
                    out.add_image(folder / f"{names[index]}.compare.png", image)
                out.commit()
            rows[index] = summary_row(job.name, payload, path=path.name)
        if on_result is not None:
            on_result(index, result)

    if todo:
        fit_many(
            [jobs[i] for i in todo],
            [jobs[i].scene for i in todo],
            [jobs[i].options for i in todo],
            executor=executor,
            chunk_size=chunk_size,
            progress=progress,
            on_result=arrived,
        )
    final_rows = [row for row in rows if row is not None]
    _create(folder)
    write_summary(summary, final_rows)
    return FolderRun(final_rows, len(todo) - counts["failed"], len(jobs) - len(todo), counts["failed"], summary)


def _create(folder: Path) -> None:
    """Create the output folder (once the work has started: see the module docstring)."""
    if folder.is_dir():
        return
    try:
        folder.mkdir()
    except FileExistsError:
        if not folder.is_dir():
            raise StraussFitError(f"the output {folder} is a file; several targets need an output folder") from None
    except OSError as exc:
        raise StraussFitError(f"cannot create the output folder {folder}: {exc.strerror or exc}") from None


def write_summary(path: Path, rows: list[dict[str, Any]]) -> None:
    """``summary.csv``: the rows under :data:`SUMMARY_COLUMNS` (written atomically)."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=SUMMARY_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    with Outputs(force=True) as out:
        out.add_text(path, buffer.getvalue())
        out.commit()


def jobs_from_arguments(
    targets: Sequence[str],
    scene: str | None,
    manifest: str | None,
    options: FitOptions,
    *,
    mask: str | None = None,
    encoding: str = "auto",
) -> list[FitJob]:
    """The jobs of the command line: TARGET arguments (files, folders, ``@LIST``) with one
    scene, and/or a manifest's rows with their own scenes. The shared ``scene`` and ``mask``
    are read here, before any work: every target would fail on them (see the module
    docstring)."""
    if scene is not None:
        load_scene(scene)
    if mask is not None:
        read_image(mask, encoding="linear")
    jobs: list[FitJob] = []
    if targets:
        if scene is None:
            raise StraussFitError("give --scene (the scene of the targets), or a --manifest with a scene column")
        jobs += [FitJob(str(path), scene, options, mask, encoding) for path in expand_targets(targets)]
    if manifest:
        jobs += [
            FitJob(row["target"], row["scene"], options, row.get("mask"), row["encoding"])
            for row in read_manifest(manifest, scene)
        ]
    if not jobs:
        raise StraussFitError("no target to fit: give TARGET arguments or a --manifest")
    return jobs

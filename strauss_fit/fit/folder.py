r"""Many targets into one folder of results: what ``strauss-fit fit T1 T2 … -o OUTDIR`` does.

For each target, ``OUTDIR/<target's file stem>.json`` (the fit result, as the single fit
writes it) and, on request, ``OUTDIR/<stem>.compare.png`` are written together as soon as
the target is fitted; at the end ``OUTDIR/summary.csv`` (one row per target, in input
order, :data:`~strauss_fit.fit.summary.SUMMARY_COLUMNS`) is rewritten. So a run that is
killed loses only the targets in flight, and ``resume`` skips every target whose result is
already there (a complete JSON result of the same target) and fits the rest, the failed
ones included. A target that fails is a row with ``status`` "failed" and its one-line
error; the others go on.

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
import io
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import OutputExistsError, StraussFitError
from ..io.files import Outputs, read_json
from ..io.images import read_image
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
            listing = Path(argument[1:])
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
    path = Path(path)
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
    """The result file stem of every target: its file stem; targets whose stems collide
    are refused (two results would overwrite each other)."""
    stems = [Path(t).stem for t in targets]
    seen: dict[str, str] = {}
    for stem, target in zip(stems, targets):
        if stem in seen and seen[stem] != str(target):
            raise StraussFitError(
                f"two targets would write the same result {stem}.json: {seen[stem]} and {target}; rename one, "
                "or fit them into different folders"
            )
        seen[stem] = str(target)
    return stems


@dataclass
class FolderRun:
    """What :func:`fit_to_folder` did: per target (input order) its summary row; counts."""

    rows: list[dict[str, Any]]
    fitted: int
    skipped: int
    failed: int
    summary: Path


def _finished(path: Path, target: str) -> dict[str, Any] | None:
    """The result JSON at ``path`` if it is a complete result of ``target``, else None."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        FitResult.from_json(data)
    except Exception:
        return None
    return data if str(data.get("target")) == str(target) else None


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
) -> FolderRun:
    """Fit ``jobs`` into ``folder`` (see the module docstring). ``recorded(job)`` gives the
    extra keys each result JSON records (the command line's target, scene, mask, encoding,
    quality). Existing results are refused unless ``resume`` (keep them, fit the rest) or
    ``force`` (fit everything again), all before any work."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise StraussFitError(f"the output {folder} is a file; several targets need an output folder")
    if not folder.exists():
        if not folder.parent.is_dir():
            raise StraussFitError(f"the output folder's parent does not exist: {folder.parent}")
        try:
            folder.mkdir()
        except OSError as exc:
            raise StraussFitError(f"cannot create the output folder {folder}: {exc.strerror or exc}") from None
    if resume and force:
        raise StraussFitError("give --resume or --force, not both")
    names = result_names([job.name for job in jobs])
    paths = [folder / f"{name}.json" for name in names]
    if resume:  # a killed run's half-written temporaries of these results
        for name in names:
            for stale in folder.glob(f".{name}.*.tmp*"):
                stale.unlink(missing_ok=True)
    summary = folder / SUMMARY_NAME
    rows: list[dict[str, Any] | None] = [None] * len(jobs)
    todo = []
    for index, (job, path) in enumerate(zip(jobs, paths)):
        done = _finished(path, job.name) if resume and path.exists() else None
        if done is not None:
            rows[index] = summary_row(job.name, done, path=path.name)
        else:
            todo.append(index)
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
    write_summary(summary, final_rows)
    return FolderRun(final_rows, len(todo) - counts["failed"], len(jobs) - len(todo), counts["failed"], summary)


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

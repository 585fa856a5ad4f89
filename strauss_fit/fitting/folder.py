r"""Many targets into one folder of results: what ``strauss-fit fit T1 T2 … -o OUTDIR`` does.

For each target, ``OUTDIR/<target's file stem>.json`` (the fit result, as the single fit
writes it) and, on request, ``OUTDIR/<stem>.compare.png`` are written together as soon as
the target is fitted; at the end ``OUTDIR/summary.csv`` (one row per target, in input
order, `SUMMARY_COLUMNS`) is rewritten. So a run that is
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
  the key made of them with strauss-fit's version (`run_key`).
  ``resume`` keeps a result whose key is this run's; a result of another configuration (or
  one without a key) is refused with what differs, never silently kept; a result missing its
  core keys (`CORE_KEYS`: hand-edited, say) is incomplete and fitted again, as is a
  kept result without the comparison image ``compare`` asks for.
- **Outputs go where files may go.** A folder, a device or a FIFO at an output's path is
  refused (`check_replaceable`), ``force`` or not.
- **Each target once.** The same target given twice, and two targets whose results would
  share a name, are refused.
- The folder itself is created only once the work has started (the cluster reached, the
  first result in), so a run that cannot start leaves nothing behind.

Targets can be files, folders (their images: every file OpenImageIO reads, sorted), lists
(``@list.txt``: one path per line, ``#`` comments) or a manifest (CSV or JSON) that pairs
each target with its own scene, mask and encoding.

What every target shares — the ``--scene`` and ``--mask`` of the command line — is read
before any work (`jobs_from_arguments`): a missing or broken one would fail every
target, so it is bad input (one line, exit status 2), as with a single target. What
belongs to one target — the image, a manifest row's own scene or mask — fails that target
alone.

**Another reflectance model** than Strauss (``fit … --model NAME -o OUTDIR``): ``model``
(a `ModelFit`) fits each target as ``fit TARGET --scene S --model NAME`` fits one
(the target and its scene as a capture of one image, then the capture fitter), one target
after the other in this process, and writes its result JSON unchanged but for its
``provenance``. Everything above holds as it is; ``summary.csv`` then has the model's
columns (`ModelFit.columns`), and there is no comparison image (no fitted image) and
no executor.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import io
import json
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import CaptureError, OutputExistsError, StraussFitError
from ..io.files import Outputs, check_input_file, check_replaceable, read_json
from ..io.images import add_image, read_image
from ..io.journal import file_digest, pytree_digest, run_key
from ..io.targets import Target
from ..runtime import release_compiled_code_if_needed
from ..scene.loading import Scene, load_scene
from ..stats.noise import sidecar_path
from .batch import DEFAULT_CHUNK, BatchProgress, FitFailure, FitJob, _failure, _loaded, fit_many
from .capture import CaptureFitOptions, _parameters
from .capture_result import check_capture_result, fit_capture, is_capture_result
from .options import FitOptions
from .result import FitResult
from .scene_samples import samples_from_scene
from .summary import SUMMARY_COLUMNS, _number, comparison_image, standardized_map, summary_row

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
    """The rows of a CSV or JSON manifest (columns `MANIFEST_COLUMNS`; paths relative
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
        data = json.loads(candidate.read_text(encoding="utf-8"))
    except Exception:
        return candidate
    return None if is_result(data) else candidate


def is_result(data: Any) -> bool:
    """Whether ``data`` (a parsed JSON file) is a fit result: a Strauss fit's
    (`FitResult`) or another model's (a capture's result,
    `is_capture_result`, as ``fit --model`` writes it)."""
    if is_capture_result(data):
        try:
            check_capture_result(data)
        except CaptureError:
            return False
        return True
    try:
        FitResult.from_json(data)
    except Exception:
        return False
    return True


def check_outputs_are_not_inputs(
    outputs: Sequence[Path], jobs: Sequence[FitJob], inputs: Sequence[str | Path] = ()
) -> None:
    """Refuse, before any work, an output that is one of the run's inputs: a target, its
    sidecar (`sidecar_of`), a scene, a mask, or one of ``inputs`` (the manifest,
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


def provenance(job: FitJob, model: ModelFit | None = None) -> dict[str, Any] | None:
    """What decides a target's result, as digests (``target_sha256`` of the image's bytes,
    ``scene_sha256``, ``mask_sha256``, ``settings_sha256`` of the options and encoding),
    strauss-fit's version, and ``key``, the run key of them all. None when an input cannot
    be read (the fit then fails on it and says why). With ``model`` (another reflectance
    model) the options are the model's (`ModelFit.as_dict`), not the job's."""

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
    options = job.options.as_dict() if model is None else model.as_dict()
    settings = json.dumps({"options": options, "encoding": job.encoding}, sort_keys=True, default=str)
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
    """What `fit_to_folder` did: per target (input order) its summary row; counts."""

    rows: list[dict[str, Any]]
    fitted: int
    skipped: int
    failed: int
    summary: Path


#: The columns of a model's ``summary.csv`` before its values, and after their ``sd_*``.
MODEL_SUMMARY_HEAD = ("target", "status", "error", "model", "verdict", "chi2_per_dof_at_floor", "chi2_per_dof_at_bound")
MODEL_SUMMARY_TAIL = ("free", "rms", "relative_rms", "delta_e2000_mean", "solver_status", "warnings", "result")


@dataclass(frozen=True)
class ModelFit:
    """Another reflectance model than Strauss fitted to every target of a folder, each as
    ``fit TARGET --scene S --model NAME`` fits one: the target and its scene as a capture of
    one image (`samples_from_scene`), then
    `fit_capture` with ``options`` and the equivalence
    ranges asked for."""

    options: CaptureFitOptions
    equivalence: bool = False
    equivalence_de: float | None = None

    @property
    def model(self) -> str:
        return self.options.model

    def as_dict(self) -> dict[str, Any]:
        """Every setting that decides a result (for its provenance)."""
        return {
            **dataclasses.asdict(self.options),
            "equivalence": self.equivalence,
            "equivalence_de": self.equivalence_de,
        }

    def _values(self) -> list[tuple[str, list[str]]]:
        """Each fitted parameter (the registry's, less those a capture holds, and the
        capture's own, e.g. a fitted exposure) and its columns: the name, or for an RGB
        triple ``NAME_r``, ``NAME_g``, ``NAME_b`` (as ``color_r`` … in a Strauss summary)."""
        out = []
        for parameter in _parameters(self.options, 1):
            if parameter.size == 1:
                names = [parameter.name]
            elif parameter.size == 3:
                names = [f"{parameter.name}_{channel}" for channel in "rgb"]
            elif parameter.name == "white_balance":  # the red and blue gains (green is 1)
                names = [f"{parameter.name}_r", f"{parameter.name}_b"]
            else:
                names = [f"{parameter.name}_{i + 1}" for i in range(parameter.size)]
            out.append((parameter.name, names))
        return out

    @property
    def columns(self) -> tuple[str, ...]:
        """The columns of this model's ``summary.csv`` (see docs/formats.md): the same for
        every run of the model and its options."""
        values = [name for _, names in self._values() for name in names]
        return (*MODEL_SUMMARY_HEAD, *values, *(f"sd_{name}" for name in values), *MODEL_SUMMARY_TAIL)

    def row(self, target: str, result: dict[str, Any] | None, *, error: str | None = None, path: str = "") -> dict:
        """One row of ``summary.csv`` for a fitted target (its result JSON) or a failed one."""
        row = dict.fromkeys(self.columns, "")
        row.update(target=target, model=self.model)
        if result is None:
            row.update(status="failed", error=error or "")
            return row
        residual = result.get("residual") or {}
        row.update(
            status="ok",
            verdict=residual.get("verdict") or "",
            chi2_per_dof_at_floor=_number(residual.get("chi2_per_dof_at_floor")),
            chi2_per_dof_at_bound=_number(residual.get("chi2_per_dof_at_bound")),
            free=" ".join(result.get("free") or []),
            rms=_number(residual.get("rms")),
            relative_rms=_number(residual.get("relative_rms")),
            delta_e2000_mean=_number(residual.get("delta_e2000_mean")),
            solver_status=(result.get("solver") or {}).get("status", ""),
            warnings=" ".join(w["code"] for w in result.get("warnings") or []),
            result=path,
        )
        values, deviations = result.get("values") or {}, result.get("uncertainty") or {}
        for name, columns in self._values():
            for prefix, source in (("", values), ("sd_", deviations)):
                given = source.get(name)
                for column, value in zip(columns, given if isinstance(given, list) else [given]):
                    row[prefix + column] = _number(value)
        return row

    def fit(self, job: FitJob, scenes: dict[str, Scene]) -> dict[str, Any]:
        """The result of one target, as ``fit TARGET --scene S --model NAME -o R.json`` writes
        it (``scenes``: the scenes loaded so far, by path)."""
        scene, target = _loaded(job, scenes)
        return fit_capture(
            samples_from_scene(scene, target),
            self.options,
            inputs={
                "target": job.name,
                "scene": str(job.scene) if isinstance(job.scene, (str, Path)) else None,
                "mask": None if job.mask is None else str(job.mask),
                "encoding": job.encoding,
            },
            equivalence=self.equivalence,
            equivalence_de=self.equivalence_de,
        )

    def fit_all(
        self,
        jobs: Sequence[FitJob],
        *,
        progress: Callable[[BatchProgress], None] | None = None,
        on_result: Callable[[int, dict[str, Any] | FitFailure], None] | None = None,
    ) -> None:
        """Fit ``jobs`` one after the other in this process; ``on_result(index, result)``
        with each result (a result JSON, or a `FitFailure`),
        then ``progress``, as `fit_many` calls them. The
        capture fitter compiles its program once per data shape: the targets of one scene,
        size and mask reuse it."""
        scenes: dict[str, Scene] = {}
        started = time.perf_counter()
        failed = 0
        for index, job in enumerate(jobs):
            release_compiled_code_if_needed()
            try:
                result: dict[str, Any] | FitFailure = self.fit(job, scenes)
            except Exception as error:  # a target that cannot be read or fitted fails alone
                result = _failure(job, error)
            failed += isinstance(result, FitFailure)
            if on_result is not None:
                on_result(index, result)
            if progress is not None:
                progress(BatchProgress(index + 1, len(jobs), failed, time.perf_counter() - started))


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _complete(data: dict[str, Any]) -> bool:
    """Whether a result holds every core key (`CORE_KEYS`) with numbers where numbers
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
    except Exception:
        return None, None  # not JSON (a half-written file): nothing to keep
    if not is_result(data):
        return None, None  # not a result (a half-edited file): nothing to keep
    # a result of another model is a result too: its provenance key (the settings name the
    # model) refuses it below, rather than letting this run overwrite it unasked
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
    on_result: Callable[[int, FitResult | dict[str, Any] | FitFailure], None] | None = None,
    inputs: Sequence[str | Path] = (),
    log: Callable[[str], None] | None = None,
    model: ModelFit | None = None,
) -> FolderRun:
    """Fit ``jobs`` into ``folder`` (see the module docstring for the rules). ``recorded(job)``
    gives the extra keys each result JSON records (the command line's target, scene, mask,
    encoding, quality); ``inputs`` names further input files no output may replace (a
    manifest, target lists); ``log`` receives a line about results fitted again. Existing
    results are refused unless ``resume`` (keep those of this run, fit the rest) or
    ``force`` (fit everything again), all before any work. ``model`` fits another
    reflectance model than Strauss (the jobs' own options are then unused)."""
    folder = Path(folder)
    _check_request(folder, resume=resume, force=force, compare=compare, executor=executor, model=model)
    row_of = summary_row if model is None else model.row
    layout = _FolderLayout(folder, result_names([job.name for job in jobs]), compare)
    _check_outputs(layout, jobs, inputs, resume=resume, force=force)
    keys = [provenance(job, model) for job in jobs]
    rows, todo = _kept_results(layout, jobs, keys, row_of, resume=resume, log=log)
    counts = {"failed": 0}

    def arrived(position: int, result: FitResult | dict[str, Any] | FitFailure) -> None:
        index = todo[position]
        job, path = jobs[index], layout.paths[index]
        if isinstance(result, FitFailure):
            rows[index] = row_of(job.name, None, error=result.message)
            counts["failed"] += 1
        else:
            payload = _payload(result, recorded(job) if recorded else {}, keys[index])
            _write_result(layout, index, payload, result)
            rows[index] = row_of(job.name, payload, path=path.name)
        if on_result is not None:
            on_result(index, result)

    if todo and model is not None:
        model.fit_all([jobs[i] for i in todo], progress=progress, on_result=arrived)
    elif todo:
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
    write_summary(layout.summary, final_rows, SUMMARY_COLUMNS if model is None else model.columns)
    return FolderRun(final_rows, len(todo) - counts["failed"], len(jobs) - len(todo), counts["failed"], layout.summary)


@dataclass
class _FolderLayout:
    """Where a folder run writes: per target (input order) its result file and, with
    ``compare``, its comparison image; and ``summary.csv``."""

    folder: Path
    #: every target's result file stem (`result_names`)
    names: list[str]
    compare: bool
    #: every target's result JSON
    paths: list[Path] = dataclasses.field(init=False)
    summary: Path = dataclasses.field(init=False)

    def __post_init__(self) -> None:
        self.paths = [self.folder / f"{name}.json" for name in self.names]
        self.summary = self.folder / SUMMARY_NAME

    def compare_image(self, index: int) -> Path:
        """The comparison image of the target at ``index``."""
        return self.folder / f"{self.names[index]}.compare.png"

    def outputs(self) -> list[Path]:
        """Every file the run may write."""
        images = [self.compare_image(index) for index in range(len(self.names))] if self.compare else []
        return [*self.paths, self.summary, *images]


def _check_request(
    folder: Path, *, resume: bool, force: bool, compare: bool, executor: Any, model: ModelFit | None
) -> None:
    """Refuse, before any work, flags that do not go together and an output folder that is
    a file or cannot be created."""
    if resume and force:
        raise StraussFitError("give --resume or --force, not both")
    if model is not None and compare:
        raise StraussFitError(f"the {model.model} model's fit draws no comparison image: fit without compare")
    if model is not None and executor is not None:
        raise StraussFitError(f"the {model.model} model's targets are fitted in this process: give no executor")
    if folder.exists() and not folder.is_dir():
        raise StraussFitError(f"the output {folder} is a file; several targets need an output folder")
    if not folder.exists():
        if not folder.parent.is_dir():
            raise StraussFitError(f"the output folder's parent does not exist: {folder.parent}")
        if not os.access(folder.parent, os.W_OK):
            raise StraussFitError(f"cannot create the output folder {folder}: {folder.parent} is not writable")


def _check_outputs(
    layout: _FolderLayout, jobs: Sequence[FitJob], inputs: Sequence[str | Path], *, resume: bool, force: bool
) -> None:
    """Refuse, before any work, an output that is an input or cannot be replaced, and,
    unless ``resume`` or ``force``, results or a summary already there."""
    outputs = layout.outputs()
    check_outputs_are_not_inputs(outputs, jobs, inputs)
    for output in outputs:  # a folder or a device where a result must go: refused, whatever the flags
        check_replaceable(output)
    if resume or force:
        return
    # results are the targets' JSON files; summary.csv is not one, but would be replaced
    existing = [p for p in layout.paths if p.exists()]
    if existing:
        raise OutputExistsError(
            f"{len(existing)} result(s) already in {layout.folder} (e.g. {existing[0].name}); pass --resume to keep "
            "them and fit the rest, or --force to fit everything again"
        )
    if layout.summary.exists():
        raise OutputExistsError(
            f"{layout.folder} already holds a {SUMMARY_NAME} from an earlier run; pass --resume to keep its results "
            "and fit the rest, or --force to replace it"
        )


def _kept_results(
    layout: _FolderLayout,
    jobs: Sequence[FitJob],
    keys: Sequence[dict[str, Any] | None],
    row_of: Callable[..., dict[str, Any]],
    *,
    resume: bool,
    log: Callable[[str], None] | None,
) -> tuple[list[dict[str, Any] | None], list[int]]:
    """The summary rows of the results ``resume`` keeps (None for the others) and the
    indices of the targets to fit; a result of another run refuses the run (`_kept`).
    A killed run's half-written temporaries of these results are removed."""
    folder, paths = layout.folder, layout.paths
    rows: list[dict[str, Any] | None] = [None] * len(jobs)
    todo, incomplete, uncompared = [], 0, 0
    for index, (job, path) in enumerate(zip(jobs, paths)):
        done, refused = _kept(path, keys[index]) if resume and path.exists() else (None, None)
        if refused is not None:
            raise OutputExistsError(
                f"{path} is not a result of this run: {refused}; resuming would mix two configurations: pass "
                "--force to fit every target again with this one, or fit into another folder"
            )
        if done is not None and layout.compare and not layout.compare_image(index).is_file():
            done, uncompared = None, uncompared + 1  # its comparison image needs the fit's images: fit again
        elif done is None:
            incomplete += resume and path.exists()
        if done is not None:
            rows[index] = row_of(job.name, done, path=path.name)
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
        for name in layout.names:
            for stale in folder.glob(f".{name}.*.tmp*"):
                stale.unlink(missing_ok=True)
    return rows, todo


def _payload(
    result: FitResult | dict[str, Any], recorded: dict[str, Any], key: dict[str, Any] | None
) -> dict[str, Any]:
    """A target's result JSON as the folder keeps it: with the ``recorded`` keys (merged
    into a part the result has, e.g. its settings) and its provenance ``key``."""
    # another model's result is already its JSON (what ``fit --model`` writes)
    payload = result if isinstance(result, dict) else result.to_json()
    for name, value in recorded.items():
        if isinstance(value, dict) and isinstance(payload.get(name), dict):
            payload[name].update(value)  # e.g. settings: the quality preset's name
        else:
            payload[name] = value
    if key is not None:
        payload["provenance"] = key
    return payload


def _write_result(
    layout: _FolderLayout, index: int, payload: dict[str, Any], result: FitResult | dict[str, Any]
) -> None:
    """The files of the target at ``index`` written together: its result JSON and, with
    ``compare``, its comparison image (the folder created if this is the first)."""
    _create(layout.folder)
    with Outputs(force=True) as out:  # this target's files together
        out.add_json(layout.paths[index], payload)
        if layout.compare and result.fitted_image is not None and result.target_image is not None:
            target = result.target_image
            image = comparison_image(
                target, result.fitted_image, result.mask, standardized_map(result, target.shape[:2])
            )
            add_image(out, layout.compare_image(index), image)
        out.commit()


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


def write_summary(path: Path, rows: list[dict[str, Any]], columns: Sequence[str] = SUMMARY_COLUMNS) -> None:
    """``summary.csv``: the rows under ``columns`` (`SUMMARY_COLUMNS`, or another
    model's `ModelFit.columns`; written atomically)."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=columns, lineterminator="\n")
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

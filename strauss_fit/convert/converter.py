r"""Converting Phong materials to Strauss parameters and back, by fitting sphere renders.

Both directions render the source material on the *conversion scene* and fit the other
model to that image by least squares, starting from a closed-form guess:

- **Phong → Strauss** (`Converter.phong_to_strauss`): the target is the Phong
  rendering (`strauss_fit.rendering.phong.render_phong`); C, s and m are fitted with the
  Strauss fit's machinery (`strauss_fit.fitting.problem.build_problem`, its start grid
  (`strauss_fit.fitting.starts.starts`), its bound-aware polish
  (`strauss_fit.fitting.solvers.polish`) and its Laplace uncertainty
  (`strauss_fit.stats.laplace.problem_laplace`)). Transparency and index of refraction
  are not visible in a local rendering over black: the fit matches the *opaque* appearance
  (t = 0), and t = 1 − opacity (``d`` of a ``.mtl``) and n (``Ni``) are carried over as
  given. Strauss's t scales both its diffuse and its base specular reflectivity by
  (1 − t), as a dissolve d = 1 − t scales a Phong surface, so the pair stays consistent.
- **Strauss → Phong** (`Converter.strauss_to_phong`): the target is the Strauss
  rendering of the opaque material (local model); D = kd·Cd, S = ks·Cs and the exponent are
  fitted (`strauss_fit.convert.phong_fit`); opacity = 1 − t and n are carried over.

The conversion scene (``data_synth/scenes/conversion_default.toml``, overridable): an
orthographic 64 × 64 view of the unit sphere (V = +z) under three white directional lights
at 0°, about 45° and about 76° from the view direction, from three different azimuths,
no ambient light, black background, local model only (depth 1: Phong has no global model,
and any scene given is rendered at depth 1). Each light's highlight sits on its own part
of the sphere, so one image holds the lobes at three angles between light and viewer, and
across the sphere every angle of incidence and of view from 0° to 90°.

Batches: `CHUNK` materials are converted together, each written as steps whose
kernel calls (the starts, the polish, the Jacobian, the renders) run as one compiled call
over the materials (`strauss_fit.convert._batches.stream`,
`strauss_fit.engine.run_batched`).
A material that fails is reported with ``status: "error"`` and a message, and the batch
goes on.

Residuals are over the sphere's pixels of the conversion image: RMS of the linear RGB
difference, its largest absolute value, and the mean and 95th percentile of the per-pixel
CIEDE2000 difference (`strauss_fit.color.delta_e_2000`). Uncertainties
are Laplace (Gauss–Newton) standard deviations, `\sigma^2 (J^\top J)^{-1}` with
`\sigma^2` = RSS/(N − P): with a noise-free target the residual is the models'
mismatch, so they say how loosely the *mismatch* pins each parameter, not a noise level.

Entry points: `phong_to_strauss` and `strauss_to_phong` convert materials,
`convert_files` reads the inputs and writes the document the command line writes.

The work is split by direction: `Converter` holds what both share (the scene, the
settings, the Strauss problems: `strauss_fit.convert._problems`) and hands each
material to the steps of its direction, `strauss_fit.convert._to_strauss` (Phong →
Strauss) or `strauss_fit.convert._to_phong` (Strauss → Phong), which start from the
closed-form guesses of `strauss_fit.convert._guesses` and run on the batch driver
of `strauss_fit.convert._batches`.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import numpy as np

from ..errors import StraussFitError
from ..fitting.options import DEFAULT_QUALITY, FitOptions, quality_preset
from ..fitting.problem import render_at
from ..io.files import check_distinct, check_writable
from ..io.journal import Journal, run_key
from ..io.material_tables import Entry as Entry
from ..io.material_tables import output_format, read_phong_input, read_strauss_input, write_results
from ..models.material import Material
from ..models.phong import PhongMaterial
from ..precision import uses_float64
from ..scene.loading import Scene, load_scene
from . import _to_phong, _to_strauss
from ._batches import Direction, stream
from ._batches import Progress as Progress
from ._guesses import GUESS_ANGLE_DEG as GUESS_ANGLE_DEG
from ._guesses import metallic_tint as metallic_tint
from ._guesses import phong_guess as phong_guess
from ._guesses import strauss_guess as strauss_guess
from ._problems import COARSE_STRIDE as COARSE_STRIDE
from ._problems import STRAUSS_FREE as STRAUSS_FREE
from ._problems import StraussProblems
from ._shared import phong_pixels as phong_pixels
from ._to_phong import BLACK_LEVEL as BLACK_LEVEL
from ._to_strauss import SAME_LOOK_DE as SAME_LOOK_DE
from .phong_fit import phong_problem

# The public names, for the API reference (mkdocstrings renders a name imported from a
# private module only when it is listed here).
__all__ = [
    "BLACK_LEVEL",
    "CHUNK",
    "COARSE_STRIDE",
    "DEFAULT_SCENE_NAME",
    "DIRECTIONS",
    "GUESS_ANGLE_DEG",
    "SAME_LOOK_DE",
    "STRAUSS_FREE",
    "Converter",
    "Progress",
    "Settings",
    "conversion_scene",
    "convert_files",
    "default_scene_path",
    "metallic_tint",
    "phong_guess",
    "phong_pixels",
    "phong_to_strauss",
    "progress_path",
    "strauss_guess",
    "strauss_to_phong",
]

#: Materials converted together (`strauss_fit.convert._batches.stream`): their
#: kernel calls run as one compiled call each (`strauss_fit.engine.run_batched`).
CHUNK = 64
#: The default conversion scene, in ``data_synth/scenes``.
DEFAULT_SCENE_NAME = "conversion_default.toml"


def default_scene_path() -> Path:
    """``data_synth/scenes/conversion_default.toml`` (installed beside the package)."""
    spec = importlib.util.find_spec("data_synth")
    roots = list(spec.submodule_search_locations) if spec and spec.submodule_search_locations else []
    roots.append(str(Path(__file__).resolve().parent.parent / "data_synth"))
    for root in roots:
        path = Path(root) / "scenes" / DEFAULT_SCENE_NAME
        if path.is_file():
            return path
    raise StraussFitError(f"the default conversion scene {DEFAULT_SCENE_NAME} is missing from the installation")


def conversion_scene(path: str | Path | None = None, size: int | None = None) -> Scene:
    """The conversion scene (default or ``path``), at depth 1 and optionally ``size`` × ``size``
    pixels (a non-square camera keeps its aspect ratio, ``size`` setting the width)."""
    scene = load_scene(path or default_scene_path())
    if size is not None:
        if size < 4:
            raise StraussFitError(f"the conversion image must be at least 4 pixels wide, got {size}")
        height = max(1, round(size * scene.camera.height / scene.camera.width))
        scene = scene.resized(size, height)
    if scene.depth != 1:
        scene = dataclasses.replace(scene, depth=1)
    return scene


# --- settings -----------------------------------------------------------------------------


_BALANCED = quality_preset(DEFAULT_QUALITY)


@dataclass(frozen=True)
class Settings:
    """Solver settings of a conversion (recorded in the output). The defaults of
    ``starts``, ``max_steps``, ``rtol`` and ``atol`` are the ``balanced`` quality preset
    (`strauss_fit.fitting.options.QUALITY_PRESETS`), the command line's default, so that
    ``Settings()`` and ``strauss-fit phong2strauss`` agree; `preset` gives the others."""

    starts: int = int(_BALANCED["starts"])
    start_steps: int = 40
    max_steps: int = int(_BALANCED["max_steps"])
    rtol: float = float(_BALANCED["rtol"])
    atol: float = float(_BALANCED["atol"])
    chunk: int = CHUNK

    @classmethod
    def preset(cls, name: str = DEFAULT_QUALITY, **overrides: Any) -> Settings:
        """The solver settings of quality preset ``name``
        (`strauss_fit.fitting.options.QUALITY_PRESETS`: ``starts``, ``max_steps``,
        ``rtol``, ``atol``), with ``overrides`` (a value of None keeps the preset's)."""
        values = quality_preset(name)
        settings = {key: values[key] for key in ("starts", "max_steps", "rtol", "atol")}
        settings.update({key: value for key, value in overrides.items() if value is not None})
        return cls(**settings)

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


class Converter:
    """Converts materials on one conversion scene (compiled once, reused for every batch).

    Each material's conversion is written as steps (`strauss_fit.engine`): the
    numeric work — the starts, the polish, the Jacobian, the renders — is yielded as
    kernel calls, and the batch driver (`strauss_fit.convert._batches.stream`)
    drives the steps of `Settings.chunk` materials together with
    `strauss_fit.engine.run_batched`, which runs the calls of the same kernel as one
    compiled call over the materials (one after another on a CPU, side by side on an
    accelerator), while the per-material decisions stay plain Python.

    The converter holds what both directions share — the scene, the settings, the fit
    options, the Strauss problems (`problems`) and the Phong one — and the steps of
    each direction are in their own module (`strauss_fit.convert._to_strauss`,
    `strauss_fit.convert._to_phong`)."""

    @uses_float64
    def __init__(self, scene: Scene | None = None, settings: Settings = Settings(), scene_label: str | None = None):
        self.scene = scene if scene is not None else conversion_scene()
        if self.scene.depth != 1:
            self.scene = dataclasses.replace(self.scene, depth=1)
        self.scene_label = scene_label or "built-in conversion scene"
        self.settings = settings
        self.options = FitOptions(
            solver="lm",
            starts=settings.starts,
            max_steps=settings.max_steps,
            start_steps=settings.start_steps,
            rtol=settings.rtol,
            atol=settings.atol,
            free=STRAUSS_FREE,
            # the conversion image is rendered here, at pixel centres: its edge pixels would be
            # exact, but the conversions were measured without them (benchmarks/convert_speed.py)
            edge_pixels="exclude",
        )
        self.problems = StraussProblems(self.scene, self.options)
        # the Strauss problem freeing C, s and m, its opaque base material, the pixels used
        # and the coarse subsample the starts run on (the study reads the first three)
        self.strauss = self.problems.full
        self.base = self.problems.base
        self.index = self.problems.index
        self.coarse = self.problems.coarse
        self.phong_template = phong_problem(self.scene, self.index)
        self.batched = jax.default_backend() != "cpu"

    # -- description ---------------------------------------------------------------------

    def describe(self) -> dict[str, Any]:
        """The scene and settings, for the output file."""
        lights = []
        directional = self.scene.lights.directional
        if directional is not None:
            for d, i, c in zip(
                np.asarray(directional.direction), np.asarray(directional.intensity), np.asarray(directional.color)
            ):
                light = {
                    "kind": "directional",
                    "direction": np.round(d, 6).tolist(),
                    "intensity": float(i),
                    "color": c.tolist(),
                }
                if self.scene.camera.projection == "orthographic":  # V = +z everywhere
                    light["angle_to_view_deg"] = round(math.degrees(math.acos(float(np.clip(d[2], -1, 1)))), 2)
                lights.append(light)
        if self.scene.lights.point is not None:
            lights.append({"kind": "point", "count": int(self.scene.lights.point.intensity.shape[0])})
        if self.scene.lights.ambient is not None:
            lights.append({"kind": "ambient", "intensity": float(self.scene.lights.ambient)})
        return {
            "file": self.scene_label,
            "width": self.scene.camera.width,
            "height": self.scene.camera.height,
            "projection": self.scene.camera.projection,
            "depth": 1,
            "pixels_used": int(self.index.size),
            "lights": lights,
        }

    # -- targets -------------------------------------------------------------------------

    @uses_float64
    def phong_target(self, phong: PhongMaterial) -> np.ndarray:
        """The Phong rendering (N, 3) at the used pixels."""
        return np.asarray(phong_pixels(self.scene, phong, self.index))

    @uses_float64
    def strauss_target(self, material: Material) -> np.ndarray:
        """The Strauss rendering (N, 3) of the opaque material at the used pixels."""
        return np.asarray(render_at(self.strauss, self.problems.vector(material)))

    # -- the two directions --------------------------------------------------------------

    @uses_float64
    def phong_to_strauss(self, entries: list[Entry], progress: Progress | None = None) -> list[dict[str, Any]]:
        """Convert every entry (Phong sources); results in input order."""
        return [result for _, result in self.iter_phong_to_strauss(entries, progress)]

    @uses_float64
    def iter_phong_to_strauss(
        self, entries: list[Entry], progress: Progress | None = None, *, start: int = 0
    ) -> Iterator[tuple[int, dict[str, Any]]]:
        """``(index, result)`` for every entry from ``start`` on, in input order, as the
        results complete (a chunk of `Settings.chunk` materials at a time)."""
        return self._stream(entries, _to_strauss.direction(self), progress, start)

    @uses_float64
    def strauss_to_phong(
        self, entries: list[Entry], progress: Progress | None = None, *, blinn: bool = False
    ) -> list[dict[str, Any]]:
        """Convert every entry (Strauss sources) to Phong (Blinn–Phong with ``blinn``)."""
        return [result for _, result in self.iter_strauss_to_phong(entries, progress, blinn=blinn)]

    @uses_float64
    def iter_strauss_to_phong(
        self, entries: list[Entry], progress: Progress | None = None, *, blinn: bool = False, start: int = 0
    ) -> Iterator[tuple[int, dict[str, Any]]]:
        """``(index, result)`` for every entry from ``start`` on, in input order, as the
        results complete."""
        return self._stream(entries, _to_phong.direction(self, blinn), progress, start)

    def _stream(
        self, entries: list[Entry], direction: Direction, progress: Progress | None, start: int
    ) -> Iterator[tuple[int, dict[str, Any]]]:
        """The entries converted in ``direction`` on the batch driver
        (`strauss_fit.convert._batches.stream`), `Settings.chunk` at a time."""
        return stream(entries, direction, progress, start, chunk=self.settings.chunk, batched=self.batched)


# --- entry points ------------------------------------------------------------------------


def _entries(materials: Any, kind: type) -> list[Entry]:
    """Materials (one, or a sequence of materials or `Entry` objects) as entries."""
    items = [materials] if isinstance(materials, (kind, Entry)) else list(materials)
    entries = []
    for number, item in enumerate(items, start=1):
        if isinstance(item, Entry):
            entries.append(item)
        elif kind is Material:
            entries.append(
                Entry(f"material-{number}", "python", item, opacity=1.0 - float(item.transparency), ior=float(item.ior))
            )
        else:
            entries.append(Entry(f"material-{number}", "python", item))
    return entries


@uses_float64
def phong_to_strauss(
    materials: PhongMaterial | Entry | Sequence[PhongMaterial | Entry],
    *,
    scene: Scene | str | Path | None = None,
    settings: Settings = Settings(),
    progress: Progress | None = None,
) -> list[dict[str, Any]]:
    """Convert Phong materials to Strauss parameters by fitting sphere renders (see the
    module docstring): one result dict per material (``status``, ``strauss``,
    ``uncertainty``, ``residual``, ``notes``, ...), in input order. ``scene`` is the
    conversion scene (a `Scene`, a scene file, or None
    for the default).

    Examples:
        >>> import strauss_fit as sf
        >>> red_plastic = sf.PhongMaterial(kd=0.7, ks=0.3, exponent=40.0, diffuse_color=(0.8, 0.1, 0.1))
        >>> [result] = sf.phong_to_strauss(red_plastic)
        >>> result["status"], round(result["strauss"]["smoothness"], 2), round(result["strauss"]["metalness"], 2)
        ('ok', 0.51, 0.36)
    """
    converter = Converter(scene if isinstance(scene, Scene) or scene is None else conversion_scene(scene), settings)
    return converter.phong_to_strauss(_entries(materials, PhongMaterial), progress)


@uses_float64
def strauss_to_phong(
    materials: Material | Entry | Sequence[Material | Entry],
    *,
    scene: Scene | str | Path | None = None,
    settings: Settings = Settings(),
    blinn: bool = False,
    progress: Progress | None = None,
) -> list[dict[str, Any]]:
    """Convert Strauss materials to Phong (Blinn–Phong with ``blinn``) by fitting sphere
    renders: one result dict per material (``status``, ``phong``, ``opacity``, ``ior``,
    ``uncertainty``, ``residual``, ``notes``, ...), in input order."""
    converter = Converter(scene if isinstance(scene, Scene) or scene is None else conversion_scene(scene), settings)
    return converter.strauss_to_phong(_entries(materials, Material), progress, blinn=blinn)


DIRECTIONS = ("phong2strauss", "strauss2phong")


def progress_path(output: str | Path) -> Path:
    """The progress file of a conversion writing ``output``: ``OUTPUT.partial`` beside it."""
    output = Path(output)
    return output.with_name(output.name + ".partial")


def _run_key(direction: str, entries: list[Entry], converter: Converter, settings: Settings, blinn: bool) -> str:
    """A digest of everything that decides a conversion's results (inputs, scene, settings,
    and strauss-fit's version: `run_key`)."""
    description = {
        "direction": direction,
        "blinn": bool(blinn),
        "settings": settings.as_dict(),
        "scene": converter.describe(),
        "entries": [entry.describe() for entry in entries],
    }
    return run_key(description)


def _with_warnings(result: dict[str, Any], entry: Entry) -> dict[str, Any]:
    """The entry's input warnings at the head of the result's notes."""
    if entry.warnings:
        result["notes"] = [f"warning: {w}" for w in entry.warnings] + list(result.get("notes", []))
    return result


@uses_float64
def convert_files(
    direction: str,
    inputs: list[str],
    output: str | Path,
    *,
    scene: str | Path | None = None,
    size: int | None = None,
    settings: Settings = Settings(),
    blinn: bool = False,
    force: bool = False,
    resume: bool = False,
    log: Callable[[str], None] | None = None,
    warn: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Read the materials of ``inputs`` (inline ``KEY=VALUE`` tokens, JSON, or ``.json``,
    ``.csv`` or ``.mtl`` files: `strauss_fit.io.material_tables`), convert them in
    ``direction`` (``phong2strauss`` or ``strauss2phong``) on the conversion scene
    (``scene``, at ``size`` pixels), write the results to ``output`` (``.json``, ``.csv``,
    or ``.mtl`` for Strauss → Phong) and return the document written (for JSON; the
    other formats hold its ``materials``). ``log`` receives progress lines, ``warn``
    warnings (inputs that are allowed but almost certainly not meant, materials renamed
    in a ``.mtl`` output).

    Results are appended to the progress file ``OUTPUT.partial``
    (`progress_path`, `strauss_fit.io.journal.Journal`) as they complete; the
    output is written atomically at the end and the progress file removed. After an
    interruption (Ctrl-C, a killed process, a full disk) ``resume`` continues from the
    progress file, with the same inputs and options, to the same output an
    uninterrupted run writes (its ``wall_time_s`` counts every run); without ``resume`` an
    existing progress file is refused unless ``force``."""
    partial = _check_paths(direction, inputs, output, force=force, resume=resume)
    log = log or (lambda message: None)
    warn = warn or (lambda message: None)
    started = time.perf_counter()
    entries, input_notes, description = _read_inputs(direction, inputs, log, warn)
    conversion = conversion_scene(scene, size)
    converter = Converter(
        conversion, settings, scene_label=str(scene) if scene else f"data_synth/scenes/{DEFAULT_SCENE_NAME}"
    )
    journal = Journal(partial, _run_key(direction, entries, converter, settings, blinn))
    results, earlier_s = _done_before(journal, entries, direction, resume=resume, force=force, log=log)
    log(
        f"{direction}: {len(entries)} material(s) from {description}; preparing the conversion scene "
        f"({conversion.camera.width}x{conversion.camera.height})"
    )

    def progress(done: int, total: int, message: str) -> None:
        log(f"{direction}: [{done}/{total}] {message}")

    if direction == "phong2strauss":
        converted = converter.iter_phong_to_strauss(entries, progress, start=len(results))
    else:
        converted = converter.iter_strauss_to_phong(entries, progress, blinn=blinn, start=len(results))
    for index, result in converted:
        result = _with_warnings(result, entries[index])
        results.append(result)
        elapsed = round(earlier_s + time.perf_counter() - started, 3)
        journal.append([{"index": index, "elapsed_s": elapsed, "result": result}])  # kept if interrupted later
    failed = [r for r in results if r["status"] != "ok"]
    document = {
        "format": f"strauss-fit {direction}",
        "version": 1,
        "input": description,
        "input_notes": input_notes,
        "scene": converter.describe(),
        "settings": settings.as_dict(),
        "summary": {"materials": len(results), "converted": len(results) - len(failed), "errors": len(failed)},
        "wall_time_s": earlier_s + time.perf_counter() - started,
        "materials": results,
    }
    for warning in write_results(output, document, direction, force=force, final=True):
        warn(warning)
    journal.remove()
    return document


def _check_paths(direction: str, inputs: list[str], output: str | Path, *, force: bool, resume: bool) -> Path:
    """Refuse a conversion `convert_files` cannot run before any work: an unknown
    ``direction``, both ``resume`` and ``force``, an output format the direction cannot
    write, an output that is an input or not writable, an interrupted conversion neither
    resumed nor forced, or nothing to resume. Returns the progress file."""
    if direction not in DIRECTIONS:
        raise StraussFitError(f"unknown conversion {direction!r}; expected one of {', '.join(DIRECTIONS)}")
    if resume and force:
        raise StraussFitError("--resume continues an interrupted conversion and --force starts again: give one")
    output_format(output, direction)
    partial = progress_path(output)
    check_distinct(
        {"-o": output, "-o's progress file": partial},
        {f"INPUT {token}": token for token in inputs if "=" not in token and not token.lstrip().startswith("{")},
    )
    check_writable(output, force)
    check_writable(partial, True)
    if partial.exists() and not (resume or force):
        raise StraussFitError(
            f"{partial} holds an interrupted conversion to {output}: continue it with --resume, "
            "or start again with --force"
        )
    if resume and not partial.exists():
        raise StraussFitError(f"nothing to resume: {partial} does not exist")
    return partial


def _read_inputs(
    direction: str, inputs: list[str], log: Callable[[str], None], warn: Callable[[str], None]
) -> tuple[list[Entry], list[str], str]:
    """The entries of ``inputs`` (Phong sources for ``phong2strauss``, else Strauss), the
    input notes (passed to ``log``) and the description of the inputs; every entry's
    warnings go to ``warn``."""
    reader = read_phong_input if direction == "phong2strauss" else read_strauss_input
    entries, input_notes, description = reader(inputs)
    for note in input_notes:
        log(f"{direction}: note: {note}")
    for entry in entries:
        for warning in entry.warnings:
            warn(f"{entry.name}: {warning}")
    return entries, input_notes, description


def _done_before(
    journal: Journal,
    entries: list[Entry],
    direction: str,
    *,
    resume: bool,
    force: bool,
    log: Callable[[str], None],
) -> tuple[list[dict[str, Any]], float]:
    """The results an interrupted run left in the progress file (``resume``; a ``force``d
    run removes the file) and the seconds it had spent. Raises when the file's results
    are out of order or more than there are entries."""
    if not resume:
        if force:
            journal.remove()
        return [], 0.0
    records = journal.open()
    if [r.get("index") for r in records] != list(range(len(records))) or len(records) > len(entries):
        raise StraussFitError(f"{journal.path} is damaged (its results are out of order); start again with --force")
    results = [r["result"] for r in records]
    earlier_s = float(records[-1].get("elapsed_s", 0.0)) if records else 0.0
    log(f"{direction}: resuming: {len(results)} of {len(entries)} material(s) done before")
    return results, earlier_s

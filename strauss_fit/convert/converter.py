r"""Converting Phong materials to Strauss parameters and back, by fitting sphere renders.

Both directions render the source material on the *conversion scene* and fit the other
model to that image by least squares, starting from a closed-form guess:

- **Phong → Strauss** (:meth:`Converter.phong_to_strauss`): the target is the Phong
  rendering (:func:`strauss_fit.render.phong.render_phong`); C, s and m are fitted with the
  Strauss fit's machinery (:func:`strauss_fit.fit.problem.build_problem`, its start grid
  (:func:`strauss_fit.fit.starts.starts`), its bound-aware polish
  (:func:`strauss_fit.fit.solvers.polish`) and its Laplace uncertainty
  (:func:`strauss_fit.stats.laplace.problem_laplace`)). Transparency and index of refraction
  are not visible in a local rendering over black: the fit matches the *opaque* appearance
  (t = 0), and t = 1 − opacity (``d`` of a ``.mtl``) and n (``Ni``) are carried over as
  given. Strauss's t scales both its diffuse and its base specular reflectivity by
  (1 − t), as a dissolve d = 1 − t scales a Phong surface, so the pair stays consistent.
- **Strauss → Phong** (:meth:`Converter.strauss_to_phong`): the target is the Strauss
  rendering of the opaque material (local model); D = kd·Cd, S = ks·Cs and the exponent are
  fitted (:mod:`strauss_fit.convert.phong_fit`); opacity = 1 − t and n are carried over.

The conversion scene (``data_synth/scenes/conversion_default.toml``, overridable): an
orthographic 64 × 64 view of the unit sphere (V = +z) under three white directional lights
at 0°, about 45° and about 76° from the view direction, from three different azimuths,
no ambient light, black background, local model only (depth 1: Phong has no global model,
and any scene given is rendered at depth 1). Each light's highlight sits on its own part
of the sphere, so one image holds the lobes at three angles between light and viewer, and
across the sphere every angle of incidence and of view from 0° to 90°.

Batches: :data:`CHUNK` materials are converted together, each written as steps whose
kernel calls (the starts, the polish, the Jacobian, the renders) run as one compiled call
over the materials (:meth:`Converter._stream`, :func:`strauss_fit.engine.run_batched`).
A material that fails is reported with ``status: "error"`` and a message, and the batch
goes on.

Residuals are over the sphere's pixels of the conversion image: RMS of the linear RGB
difference, its largest absolute value, and the mean and 95th percentile of the per-pixel
CIEDE2000 difference (:func:`strauss_fit.color.delta_e_2000`). Uncertainties
are Laplace (Gauss–Newton) standard deviations, :math:`\sigma^2 (J^\top J)^{-1}` with
:math:`\sigma^2` = RSS/(N − P): with a noise-free target the residual is the models'
mismatch, so they say how loosely the *mismatch* pins each parameter, not a noise level.

Entry points: :func:`phong_to_strauss` and :func:`strauss_to_phong` convert materials,
:func:`convert_files` reads the inputs and writes the document the command line writes.
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
import jax.numpy as jnp
import numpy as np

from ..color import delta_e_2000
from ..engine import Kernel, Steps, run_batched
from ..errors import StraussFitError
from ..fit.diagnosis import WEAK_FRACTION
from ..fit.identifiability import (
    Decision,
    deviation_scale,
    held_at_optimum,
    numerical_decision,
    reference_noise_level,
)
from ..fit.options import DEFAULT_QUALITY, VISIBLE_DELTA_E, FitOptions, quality_preset
from ..fit.parameters import jsonable, material_with
from ..fit.problem import build_problem, physical_values, render_at, take_pixels_jit
from ..fit.solvers import STRICT_REJECT_RATIO, polish_steps, solve_starts
from ..fit.starts import START_MARGIN, starts
from ..io.files import check_distinct, check_writable
from ..io.journal import Journal, run_key
from ..io.material_tables import Entry, output_format, read_phong_input, read_strauss_input, write_results
from ..io.targets import Target
from ..models.material import OPAQUE_NAMES, Material
from ..models.phong import MAX_EXPONENT, PhongMaterial
from ..models.strauss import K_J, fresnel, shadow
from ..precision import uses_float64
from ..render.phong import render_phong
from ..render.strauss import plan_render
from ..scene.loading import Scene, load_scene
from ..stats.laplace import covariance, deviations, jacobian_kernel, problem_laplace_steps
from ..stats.laplace import information as information_of
from .phong_fit import (
    PHONG_LAYOUT,
    exponent_from_unit,
    laplace_deviations_from,
    material_from_vector,
    phong_problem,
    solve_phong_starts,
    unit_from_exponent,
)

#: Strauss parameters the conversion fits (t and n are carried over, see the module docstring).
STRAUSS_FREE = OPAQUE_NAMES
#: Materials converted together (:meth:`Converter._stream`): their kernel calls run as one
#: compiled call each (:func:`strauss_fit.engine.run_batched`).
CHUNK = 64
#: The starts run on every COARSE_STRIDE-th pixel of the conversion image, the polish on all.
COARSE_STRIDE = 4
#: Two conversions whose mean CIEDE2000 to the target differ by less than this (a hundredth
#: of a just-noticeable difference) look the same: the one on the canonical branch is taken
#: (a metal for a tinted Phong highlight, a dielectric for a white one).
SAME_LOOK_DE = 0.01
#: The default conversion scene, in ``data_synth/scenes``.
DEFAULT_SCENE_NAME = "conversion_default.toml"
#: Angle (α = γ) at which the closed-form Strauss → Phong guess evaluates j and F.
GUESS_ANGLE_DEG = 30.0
#: A Strauss rendering whose largest value is at most this is black for Strauss → Phong:
#: below the first step of an 8-bit sRGB image (code 1 is 3.0e-4 linear). Strauss's
#: darkest material (C = 0, m = 1, s = 0, what Phong → Strauss gives for kd = ks = 0) is
#: not exactly black (its off-specular term reaches 7e-5); fitting it ran to the step limit.
BLACK_LEVEL = 1e-4


def _phong_pixels(scene: Scene, material: PhongMaterial, index: Any) -> Any:
    image, _ = render_phong(scene, material)
    return image.reshape(-1, 3)[index]


#: The Phong rendering (N, 3) of a material in a scene at the flat pixel ``index``; a
#: :class:`~strauss_fit.engine.Kernel`, so that a chunk's targets render as one call.
phong_pixels = Kernel(_phong_pixels, "phong_pixels")


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


# --- closed-form guesses ------------------------------------------------------------------


def _triple(value: Any) -> np.ndarray:
    return np.broadcast_to(np.asarray(value, dtype=np.float64), (3,)).copy()


def strauss_guess(phong: PhongMaterial) -> tuple[dict[str, Any], list[str]]:
    r"""Closed-form Strauss parameters for a Phong material (the fit's first start).

    With :math:`D = k_d C_d` and :math:`S = k_s C_{sp}` (RGB) and the exponent n:

    - smoothness from the lobe width: Strauss's highlight is :math:`\cos^h\beta` with
      :math:`h = 3/(1 - s)`, Phong's :math:`\cos^n\beta`, so :math:`s = 1 - 3/n`, clipped to
      [0, 1) (n ≤ 3 gives s = 0: Strauss has no lobe wider than h = 3). For Blinn–Phong,
      whose :math:`\cos^n(N\cdot H)` is close to :math:`\cos^{n/4}(R\cdot V)`, n/4 is used.
      For a pure Phong lobe the guessed s reproduces the lobe's shape exactly. Without a
      highlight (S = 0) s = 0, whatever n says.
    - metalness from the tint of the highlight: Strauss's highlight colour at small
      angles of incidence is :math:`C_s \approx (1 - m)\,\mathrm{white} + m\,C`, so with
      :math:`\hat C = D/\max D` (the diffuse hue) and the tint :math:`T = S/\max S`,
      :math:`m = (1 - \min T)/(1 - \min\hat C)`, clipped to [0, 1]; a white highlight gives
      m = 0, and so does a grey diffuse colour (no hue to compare with). Without a diffuse
      term (D = 0) a tinted highlight means a metal of that colour (m = 1, C = T), a
      white one a black dielectric (m = 0, C = 0), and no highlight either Strauss's
      darkest material (C = 0, m = 1, s = 0: its off-specular term never vanishes).
    - colour from the diffuse term: Strauss's diffuse reflectance is
      :math:`(1 - ms)(1 - s^3)\,C`, so :math:`C = D / ((1 - ms)(1 - s^3))`; where that
      exceeds 1 it is scaled down to a largest channel of 1 (keeping the hue), with a note.

    Phong's ks has no Strauss counterpart of its own: the highlight's strength follows
    from s (:math:`r_n = s^3`) and m. Returns the guess and notes.
    """
    notes: list[str] = []
    d = _triple(phong.kd) * np.asarray(phong.diffuse_color, dtype=np.float64)
    s_rgb = _triple(phong.ks) * np.asarray(phong.specular_color, dtype=np.float64)
    n = float(phong.exponent)
    n_lobe = n / 4.0 if phong.blinn else n
    d_max, s_max = float(d.max()), float(s_rgb.max())
    if s_max > 0:
        smoothness = float(np.clip(1.0 - 3.0 / n_lobe, 0.0, 1.0)) if n_lobe > 0 else 0.0
        smoothness = min(smoothness, float(np.nextafter(1.0, 0.0)))
    else:
        smoothness = 0.0  # no highlight: the matte end (any s > 0 would add one)
    tint = s_rgb / s_max if s_max > 0 else np.ones(3)
    tinted = 1.0 - float(tint.min()) > 0.05
    if d_max <= 1e-12:
        if s_max > 0 and tinted:
            metalness, color = 1.0, tint
        elif s_max > 0:
            metalness, color = 0.0, np.zeros(3)
        else:  # black: Strauss's darkest material (its off-specular term k_j j F never vanishes)
            metalness, color = 1.0, np.zeros(3)
    else:
        hue = d / d_max
        chroma = 1.0 - float(hue.min())
        metalness = float(np.clip((1.0 - float(tint.min())) / chroma, 0.0, 1.0)) if chroma > 0.05 and s_max > 0 else 0.0
        scale = (1.0 - metalness * smoothness) * (1.0 - smoothness**3)
        color = d / scale if scale > 1e-12 else hue
        if color.max() > 1.0:
            notes.append(
                f"the diffuse term kd·Cd = {np.round(d, 4).tolist()} is brighter than Strauss allows at "
                f"s = {smoothness:.3f}, m = {metalness:.3f}; the guessed colour is scaled to a largest channel of 1"
            )
            color = color / color.max()
    guess = {"color": [float(c) for c in np.clip(color, 0.0, 1.0)], "smoothness": smoothness, "metalness": metalness}
    return guess, notes


def phong_guess(material: Material) -> tuple[np.ndarray, float]:
    r"""Closed-form Phong parameters for an (opaque) Strauss material: the vector
    (D, S, u) of :data:`strauss_fit.convert.phong_fit.PHONG_LAYOUT` and the ambient coefficient.

    - n = h = 3/(1 − s) (clipped to [1, 10000]; s = 1 gives 10000);
    - D = (1 − ms)(1 − s³) C, Strauss's diffuse reflectance;
    - S = r_j C_s evaluated at α = γ = :data:`GUESS_ANGLE_DEG` (j and F there), with
      :math:`r_j = \min(1, r_n + j(r_n + k_j))`, :math:`r_n = s^3`;
    - ka = (1 − s³)·max C, so that Phong's ambient term :math:`k_a C_d` with
      :math:`C_d = D/\max D` equals Strauss's :math:`r_d C` (exactly when the diffuse hue
      is C's, which it always is).
    """
    c = np.asarray(material.color, dtype=np.float64)
    s, m = float(material.smoothness), float(material.metalness)
    h = 3.0 / (1.0 - s) if s < 1 else MAX_EXPONENT
    d = (1.0 - m * s) * (1.0 - s**3) * c
    x = 2.0 * math.radians(GUESS_ANGLE_DEG) / math.pi
    f, g = float(fresnel(x)), float(shadow(x))
    r_n = s**3
    r_j = min(1.0, r_n + f * g * g * (r_n + K_J))
    spec = r_j * (1.0 + m * (1.0 - f) * (c - 1.0))
    vector = np.concatenate([np.clip(d, 0, 1), np.clip(spec, 0, 1), [unit_from_exponent(h)]])
    return vector, float((1.0 - s**3) * c.max())


# --- the batch converter -----------------------------------------------------------------


_BALANCED = quality_preset(DEFAULT_QUALITY)


@dataclass(frozen=True)
class Settings:
    """Solver settings of a conversion (recorded in the output). The defaults of
    ``starts``, ``max_steps``, ``rtol`` and ``atol`` are the ``balanced`` quality preset
    (:data:`strauss_fit.fit.options.QUALITY_PRESETS`), the command line's default, so that
    ``Settings()`` and ``strauss-fit phong2strauss`` agree; :meth:`preset` gives the others."""

    starts: int = int(_BALANCED["starts"])
    start_steps: int = 40
    max_steps: int = int(_BALANCED["max_steps"])
    rtol: float = float(_BALANCED["rtol"])
    atol: float = float(_BALANCED["atol"])
    chunk: int = CHUNK

    @classmethod
    def preset(cls, name: str = DEFAULT_QUALITY, **overrides: Any) -> Settings:
        """The solver settings of quality preset ``name``
        (:data:`strauss_fit.fit.options.QUALITY_PRESETS`: ``starts``, ``max_steps``,
        ``rtol``, ``atol``), with ``overrides`` (a value of None keeps the preset's)."""
        values = quality_preset(name)
        settings = {key: values[key] for key in ("starts", "max_steps", "rtol", "atol")}
        settings.update({key: value for key, value in overrides.items() if value is not None})
        return cls(**settings)

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


Progress = Callable[[int, int, str], None]


def _residual_stats(model: np.ndarray, target: np.ndarray) -> dict[str, float]:
    """RMS and largest absolute difference in linear RGB, mean and 95th percentile of the
    per-pixel CIEDE2000 (:func:`strauss_fit.color.delta_e_2000`: exposed for ``target``)."""
    diff = model - target
    delta = delta_e_2000(model, target)
    return {
        "rms": float(np.sqrt(np.mean(diff**2))),
        "max_abs": float(np.max(np.abs(diff))),
        "delta_e2000_mean": float(np.mean(delta)),
        "delta_e2000_p95": float(np.percentile(delta, 95)),
    }


def _scale_of(pixels: np.ndarray) -> float:
    """Residual scale as in a fit (:mod:`strauss_fit.fit.problem`): reference noise × √(values)."""
    return reference_noise_level(pixels) * math.sqrt(pixels.size)


def _error(entry: Entry, message: str) -> dict[str, Any]:
    return {
        "name": entry.name,
        "source": entry.source,
        "status": "error",
        "message": message,
        "notes": list(entry.notes),
    }


@dataclass
class _Direction:
    """One direction of the conversion for the generic chunk driver
    (:meth:`Converter._stream`): how an item is made from an entry (``prepare``, raises
    for a bad material) and the steps that convert it (``steps``: a generator of
    :class:`strauss_fit.engine.Call`, returning the result dict)."""

    prepare: Callable[[int, Entry], tuple]
    steps: Callable[[tuple], Steps]


def _held_uncertainty(layout: Any, uncertainty: dict[str, Any], held: dict[str, Any]) -> dict[str, Any]:
    """``uncertainty`` with None for the held parameters (a held value has no interval)."""
    out = dict(uncertainty)
    for name in held:
        if name in out:
            out[name] = [None] * len(out[name]) if isinstance(out[name], list) else None
    return out


def metallic_tint(phong: PhongMaterial) -> bool:
    """Whether a Phong material's highlight is tinted — what a metal shows (its colour
    differs from white by more than 5 %, as :func:`strauss_guess` reads it)."""
    specular = _triple(phong.ks) * np.asarray(phong.specular_color, dtype=np.float64)
    top = float(specular.max())
    return top > 0 and 1.0 - float(specular.min()) / top > 0.05


class Converter:
    """Converts materials on one conversion scene (compiled once, reused for every batch).

    Each material's conversion is written as steps (:mod:`strauss_fit.engine`): the
    numeric work — the starts, the polish, the Jacobian, the renders — is yielded as
    kernel calls, and :meth:`_stream` drives the steps of :attr:`Settings.chunk` materials
    together with :func:`strauss_fit.engine.run_batched`, which runs the calls of the same
    kernel as one compiled call over the materials (one after another on a CPU, side by
    side on an accelerator), while the per-material decisions stay plain Python."""

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
        self.base = Material(transparency=0.0)
        height, width = self.scene.shape
        self._dummy = Target(
            np.ones((height, width, 3)), np.ones((height, width), dtype=bool), "<conversion>", "linear", 0, 0
        )
        self._plan = plan_render(self.scene, self.base, transparent=False)
        self._cache: dict = {}
        self.strauss, prepared_full, self.index = build_problem(
            self.scene, self._dummy, list(STRAUSS_FREE), self.base, self._plan, self.options, cache=self._cache
        )
        self._templates: dict[tuple[str, ...], Any] = {STRAUSS_FREE: self.strauss}
        # the starts run on every COARSE_STRIDE-th pixel (the polish on all of them): the
        # same optimum, a quarter of the work (benchmarks/convert_speed.py)
        self.coarse = np.arange(0, self.index.size, COARSE_STRIDE) if self.index.size >= 4 * COARSE_STRIDE else None
        self._coarse_prepared = None if self.coarse is None else take_pixels_jit(prepared_full, self.index[self.coarse])
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
        return np.asarray(render_at(self.strauss, self._strauss_vector(material)))

    def _strauss_vector(self, material: Material) -> np.ndarray:
        """The conversion problem's parameter vector (C, s, m) of ``material``."""
        return self.strauss.layout.join(material.to_dict())

    def _lobe_note(self, exponent: float) -> str | None:
        """A note when the highlight is narrower than the image's pixels resolve."""
        if exponent <= 0:
            return None
        half_width = math.acos(0.5 ** (1.0 / exponent))  # where cos^n beta = 1/2
        pitch = 2.0 * 2.0 / self.scene.camera.width  # beta moves twice as fast as the normal
        if half_width < pitch:
            return (
                f"the highlight (n = {exponent:.4g}) is narrower than a pixel of the {self.scene.camera.width}-pixel "
                "conversion image; its shape is poorly constrained (use a larger --size)"
            )
        return None

    # -- problems ------------------------------------------------------------------------

    def _template(self, free: tuple[str, ...]) -> Any:
        """The Strauss problem freeing ``free`` (built once per set of names)."""
        if free not in self._templates:
            self._templates[free], _, _ = build_problem(
                self.scene, self._dummy, list(free), self.base, self._plan, self.options, cache=self._cache
            )
        return self._templates[free]

    def _problem(self, template: Any, target: np.ndarray, scale: float, material: Material | None = None) -> Any:
        changes: dict[str, Any] = {"target": np.asarray(target), "residual_scale": np.asarray(scale)}
        if material is not None:
            changes["material"] = material.astype(jnp.float64)
        return dataclasses.replace(template, **changes)

    def _screen(self, problem: Any, target: np.ndarray, scale: float) -> Any:
        """``problem`` on the coarse subsample of pixels (the residual scale shrinks with
        the pixel count, so costs stay comparable), or itself when the image is small."""
        if self.coarse is None:
            return problem
        return dataclasses.replace(
            problem,
            prepared=self._coarse_prepared,
            target=np.asarray(target)[self.coarse],
            residual_scale=np.asarray(scale * math.sqrt(self.coarse.size / self.index.size)),
        )

    # -- Phong -> Strauss ----------------------------------------------------------------

    @uses_float64
    def phong_to_strauss(self, entries: list[Entry], progress: Progress | None = None) -> list[dict[str, Any]]:
        """Convert every entry (Phong sources); results in input order."""
        return [result for _, result in self.iter_phong_to_strauss(entries, progress)]

    @uses_float64
    def iter_phong_to_strauss(
        self, entries: list[Entry], progress: Progress | None = None, *, start: int = 0
    ) -> Iterator[tuple[int, dict[str, Any]]]:
        """``(index, result)`` for every entry from ``start`` on, in input order, as the
        results complete (a chunk of :attr:`Settings.chunk` materials at a time)."""

        def prepare(i: int, entry: Entry) -> tuple:
            material = entry.build()
            guess, notes = strauss_guess(material)
            notes = [f"closed-form guess: {note}" for note in notes]
            return (i, entry, guess, notes, material)

        return self._stream(entries, _Direction(prepare, self._strauss_steps), progress, start)

    def _stream(
        self, entries: list[Entry], direction: _Direction, progress: Progress | None, start: int
    ) -> Iterator[tuple[int, dict[str, Any]]]:
        """Prepare the entries one by one, convert them :attr:`Settings.chunk` at a time and
        yield ``(index, result)`` in input order as soon as every earlier one is done (a
        bad material is an error result; the batch goes on).

        Chunks are fixed by index (entries ``[k·chunk, (k + 1)·chunk)``), and a run from
        ``start`` (a resumed conversion) converts again the entries of its first chunk
        before ``start`` without reporting them: a material's result depends, in its last
        digits, on the batch it was computed in, and so a resumed run writes exactly what
        an uninterrupted one does."""
        report = _Reporter(progress, len(entries), start)
        done: dict[int, dict[str, Any]] = {}
        queue: list[tuple] = []
        following = start
        chunk = self.settings.chunk

        def ready() -> Iterator[tuple[int, dict[str, Any]]]:
            nonlocal following
            while following in done:
                yield following, done.pop(following)
                following += 1

        def solve() -> None:
            for item, outcome in zip(queue, self._run_chunk(queue, direction)):
                if item[0] >= start:  # the others were done before (only their batch is needed)
                    done[item[0]] = report(item[1], outcome)
                item[1].release()
            queue.clear()

        for i in range(start - start % chunk, len(entries)):
            entry = entries[i]
            if entry.error:
                if i >= start:
                    done[i] = report(entry, _error(entry, entry.error))
            else:
                try:
                    queue.append(direction.prepare(i, entry))
                except Exception as exc:  # noqa: BLE001 - one bad material never stops the batch
                    entry.release()
                    if i >= start:
                        done[i] = report(entry, _error(entry, _message(exc)))
            if (i + 1) % chunk == 0 and queue:
                solve()
            yield from ready()
        if queue:
            solve()
        yield from ready()

    def _run_chunk(self, chunk: list[tuple], direction: _Direction) -> list[dict[str, Any]]:
        """Convert the items of ``chunk`` (``(i, entry, ...)``) together: their steps run
        batched (:func:`strauss_fit.engine.run_batched`; a material that fails is an error
        result, the others go on)."""
        outcomes = run_batched(
            [direction.steps(item) for item in chunk], sequential=not self.batched, python_bound=False
        )
        return [
            _error(item[1], _message(outcome)) if isinstance(outcome, BaseException) else outcome
            for item, outcome in zip(chunk, outcomes)
        ]

    def _strauss_values(self, entry: Entry, fitted: dict[str, Any]) -> dict[str, Any]:
        return {
            "color": [float(c) for c in np.asarray(fitted["color"])],
            "smoothness": float(fitted["smoothness"]),
            "metalness": float(fitted["metalness"]),
            "transparency": float(np.clip(1.0 - entry.opacity, 0, 1)),
            "ior": float(max(entry.ior, 1.0)),
        }

    def _common_notes(self, entry: Entry, values: dict[str, Any]) -> list[str]:
        notes = []
        phong = entry.material
        if phong.blinn:
            notes.append("Blinn-Phong source: the smoothness guess used n/4 (cos^n(N·H) ≈ cos^(n/4)(R·V))")
        if entry.opacity < 1:
            notes.append(
                f"transparency t = 1 - d = {1 - entry.opacity:.4g} carried over, not fitted "
                "(the fit matches the opaque appearance)"
            )
        ka = _triple(phong.ka) * np.asarray(phong.diffuse_color, dtype=np.float64)
        r_d = (1 - values["smoothness"] ** 3) * np.asarray(values["color"])
        if float(np.max(ka)) > 0 and float(np.max(np.abs(ka - r_d))) > 0.02:
            notes.append(
                f"ka is not a Strauss parameter: Phong's ambient term ka·Cd = {np.round(ka, 3).tolist()} "
                f"becomes Strauss's ambient reflectance r_d·C = {np.round(r_d, 3).tolist()}"
            )
        lobe = self._lobe_note(float(phong.exponent) / (4.0 if phong.blinn else 1.0))
        if lobe:
            notes.append(lobe)
        return notes

    def _solve(
        self, problem: Any, thetas: np.ndarray, target: np.ndarray, scale: float, ends: tuple | None = None
    ) -> Steps:
        """Every start on the coarse pixels (:attr:`Settings.start_steps` steps), then the
        best one polished on every pixel (:func:`strauss_fit.fit.solvers.polish_steps`:
        entries at a bound pinned there). ``ends``: the starts' ends (θ, costs, steps),
        when they were solved before. Returns (x, rss, steps, status, pinned problem,
        JᵀJ, best start, the starts' ends)."""
        if ends is None:
            screen = self._screen(problem, target, scale)
            ends = tuple(
                np.asarray(v)
                for v in (
                    yield solve_starts.call(
                        screen,
                        np.asarray(thetas),
                        "lm",
                        self.settings.rtol,
                        self.settings.atol,
                        self.settings.start_steps,
                        self.batched,
                        STRICT_REJECT_RATIO,
                    )
                )
            )[:3]
        values, costs_, steps_ = ends
        finite = np.isfinite(costs_)
        if not finite.any():
            raise StraussFitError("every start of the fit diverged to non-finite values")
        best = int(np.argmin(np.where(finite, costs_, np.inf)))
        theta, cost, polish_count, status, pinned, information = yield from polish_steps(
            problem, values[best], self.options, reject_ratio=STRICT_REJECT_RATIO
        )
        x = physical_values(pinned, theta)
        if not np.all(np.isfinite(x)):
            raise StraussFitError("the fit ended at non-finite parameters")
        rss = float(cost) * float(np.asarray(problem.residual_scale)) ** 2
        return x, rss, int(steps_[best]) + polish_count, status, pinned, information, best, ends

    def _strauss_steps(self, item: tuple) -> Steps:
        """The Phong → Strauss conversion of one material, as steps (see the module
        docstring): the fit of C, s, m; for a tinted highlight the best metal too; then
        what the image constrains, decided as :func:`strauss_fit.fit` decides it, with a
        metalness the image does not determine held at the source's canonical value."""
        _, entry, guess, guess_notes, phong = item
        # rendered here, not when the item is prepared: the renders of a chunk then run as
        # one compiled call, beside other materials' Python, instead of one by one before it
        target = np.asarray((yield phong_pixels.call(self.scene, phong, self.index)))
        if not np.all(np.isfinite(target)):
            raise StraussFitError("the Phong rendering is not finite")
        if float(np.max(target)) <= 0.0:
            return self._black_strauss(entry, guess, guess_notes, target)
        layout = self.strauss.layout
        scale = _scale_of(target)
        sigma = reference_noise_level(target)
        problem = self._problem(self.strauss, target, scale)
        thetas = starts(layout, guess, self.settings.starts)
        first = yield from self._solve(problem, thetas, target, scale)
        x, rss, steps_, status, pinned, information, best, ends = first
        model = np.asarray((yield render_at.call(pinned, x)))
        notes: list[str] = []
        off_branch_note = None
        metal_index = layout.offsets[layout.names.index("metalness")]
        tinted = metallic_tint(phong)
        if tinted != (x[metal_index] >= 0.5):
            # The canonical branch: a tinted highlight is what a metal shows, a white one a
            # dielectric's. Least squares in linear RGB can land on the other: Phong gold
            # (its narrow lobe and diffuse Kd fit a smooth plastic with a white highlight,
            # ΔE 5, better in RMS than the metal, ΔE 1.6, whose diffuse term
            # (1 - ms)(1 - s^3)C ties it to a wider lobe); a grey Phong glass renders alike
            # as C = 0.23, m = 0.03 and as C = 0.98, m = 0.80 (the highlight dimmed by
            # m(1 - C) either way), and the presets ended in either. Fit again from the
            # canonical branch and take it unless it looks less close to the target.
            if tinted:
                specular = _triple(phong.ks) * np.asarray(phong.specular_color, dtype=np.float64)
                other_start = {**guess, "color": (specular / specular.max()).tolist(), "metalness": 1.0}
            else:
                other_start = {**guess, "metalness": 0.0}
            other_theta = layout.to_unconstrained(layout.join(other_start), margin=START_MARGIN)[None]
            if not np.array_equal(other_theta[0], thetas[0]):
                other = yield from self._solve(problem, other_theta, target, scale)
                other_model = np.asarray((yield render_at.call(other[4], other[0])))
            elif best == 0:  # the canonical start is the guess, and the first fit came from it
                other, other_model = first, model
            else:  # the canonical start is the guess: its end on the coarse pixels is known
                other = yield from self._solve(problem, other_theta, target, scale, tuple(v[:1] for v in ends))
                other_model = np.asarray((yield render_at.call(other[4], other[0])))
            looks = float(np.mean(delta_e_2000(model, target)))
            other_looks = float(np.mean(delta_e_2000(other_model, target)))
            rms, other_rms = math.sqrt(rss / target.size), math.sqrt(other[1] / target.size)
            kind = "a metal" if tinted else "a dielectric"
            highlight = "tinted, as a metal's" if tinted else "white, as a dielectric's"
            on_branch = tinted == (other[0][metal_index] >= 0.5)
            if on_branch and other_looks <= looks + SAME_LOOK_DE:
                notes.append(
                    f"the highlight is {highlight}: the best fit from {kind} (m = {other[0][metal_index]:.3g}, mean "
                    f"CIEDE2000 {other_looks:.3g}, linear RMS {other_rms:.3g}) is taken over the least-squares "
                    f"optimum found first (m = {x[metal_index]:.3g}, CIEDE2000 {looks:.3g}, RMS {rms:.3g}): it looks "
                    + ("closer" if other_looks < looks - SAME_LOOK_DE else "the same")
                )
                x, rss, steps_, status, pinned, information, best, _ = other
                model = other_model
            else:
                why = (
                    f"it ends at m = {other[0][metal_index]:.3g}"
                    if not on_branch
                    else f"it looks less close: mean CIEDE2000 {other_looks:.3g} against {looks:.3g}, "
                    f"linear RMS {other_rms:.3g} against {rms:.3g}"
                )
                reason = (
                    "Strauss ties a metal's diffuse term to its smoothness, (1 - ms)(1 - s^3)C, so a metal cannot "
                    "have both this highlight's width and this diffuse term"
                    if tinted
                    else "a dielectric's highlight, r_s = s^3 at normal incidence, cannot match this one's strength "
                    "at this width without a metal's tint"
                )
                # said only if the metalness stays free (below): when the image does not
                # determine it, it is held at the canonical value, and that note says why
                off_branch_note = (
                    f"the highlight is {highlight}, but the best Strauss match is not {kind}: the best fit started "
                    f"from {kind} is no better ({why}); {reason}"
                )
        fitted = jsonable(layout.split(x))
        current = _Solution(problem, pinned, x, rss, int(steps_), status, information, model)
        held: dict[str, dict[str, Any]] = {}
        canonical = float(guess["metalness"]) if tinted else 0.0
        # what the image constrains at the optimum, decided as a fit decides it there
        decision, jacobian = yield from self._decide(current, sigma)
        if decision.held:
            before = Decision(free=list(current.problem.layout.names))
            values, reasons = held_at_optimum(decision, before, fitted)
            mirror = "metalness" in values and float(values["metalness"]) == 1.0 and "mirror" in reasons["metalness"]
            for name in decision.held:
                values.setdefault(name, fitted[name])  # the image ignores it: any value; keep the fit's
                reasons.setdefault(name, f"{decision.held[name]}; held at the value the fit reached")
            if "metalness" in decision.held and not mirror:
                values["metalness"] = canonical
                reasons["metalness"] = (
                    f"the conversion image does not determine it: {decision.held['metalness']}; held at "
                    + (
                        f"{canonical:.3g}, the closed-form guess from the highlight's tint"
                        if tinted
                        else "0: the Phong source has no metallic (tinted) highlight"
                    )
                )
            refit = None
            if _changed(values, fitted) and decision.free:
                refit = yield from self._refit(
                    tuple(decision.free), {**{k: v["value"] for k, v in held.items()}, **values}, fitted, target, scale
                )
                apart = float(np.mean(delta_e_2000(refit.model, current.model)))
                if "metalness" in decision.held and not mirror and apart > VISIBLE_DELTA_E:
                    # holding it there would change what the image shows: keep the fit's value
                    values["metalness"] = fitted["metalness"]
                    reasons["metalness"] = (
                        f"{decision.held['metalness']}; held at the value the fit reached, since holding it at "
                        f"{canonical:.3g} would change the image visibly (mean CIEDE2000 {apart:.2g} from the fit)"
                    )
                    refit = None
                    if _changed(values, fitted):
                        refit = yield from self._refit(
                            tuple(decision.free),
                            {**{k: v["value"] for k, v in held.items()}, **values},
                            fitted,
                            target,
                            scale,
                        )
            held.update({name: {"value": values[name], "reason": reasons[name]} for name in decision.held})
            if refit is not None:
                fitted = {**fitted, **values, **jsonable(refit.problem.layout.split(refit.x))}
                refit.steps += current.steps
                current = refit
            else:
                # held at the fitted values: the optimum stands, the ± are conditional on them
                mask = np.array([owner in held for owner in _owners(current.problem.layout)])
                current.pinned = current.pinned.pin(mask | np.asarray(current.pinned.pinned), current.x)
                current.information = None
        final_layout = current.pinned.layout
        info = jacobian.T @ jacobian if current.information is None else current.information
        uncertainty, correlation, _ = yield from problem_laplace_steps(
            current.pinned, current.x, current.rss, None, info
        )
        uncertainty = _held_uncertainty(final_layout, uncertainty, held)
        for name in held:
            uncertainty.setdefault(name, [None] * 3 if name == "color" else None)
        at_bound_labels = [
            label
            for label, p, owner in zip(final_layout.labels(), np.asarray(current.pinned.pinned), _owners(final_layout))
            if p and owner not in held
        ]
        model, status, steps_ = current.model, current.status, current.steps
        values_out = self._strauss_values(entry, fitted)
        notes = list(entry.notes) + guess_notes + self._common_notes(entry, values_out) + notes
        if off_branch_note is not None and "metalness" not in held:
            notes.append(off_branch_note)
        if status != "successful":
            notes.append(f"the solver ended with status '{status}'")
        for name, info in held.items():
            notes.append(f"{name} held at {_value_text(info['value'])}: {info['reason']}")
        if at_bound_labels:
            notes.append(
                "at a bound, where the data push against it (its Laplace deviation, 0 there, is no symmetric "
                f"interval): {', '.join(at_bound_labels)}"
            )
        return {
            "name": entry.name,
            "source": entry.source,
            "status": "ok",
            "input": {"phong": entry.material.to_dict(), "opacity": entry.opacity, "ior": entry.ior},
            "guess": guess,
            "strauss": values_out,
            "held": held,
            "uncertainty": uncertainty,
            "correlation": correlation,
            "solver": {
                "status": status,
                "steps": int(steps_),
                "best_start": best,
                "starts": int(len(thetas)),
                "at_bound": at_bound_labels,
            },
            "notes": notes,
            # measured here, against this material's own target (its exposure scale)
            "residual": _residual_stats(model, target),
        }

    def _refit(
        self, free: tuple[str, ...], values: dict[str, Any], fitted: dict[str, Any], target: np.ndarray, scale: float
    ) -> Steps:
        """The fit again with only ``free`` fitted and the other parameters held at
        ``values`` (else their ``fitted`` value), polished from the fitted values."""
        held = {name: values.get(name, fitted[name]) for name in STRAUSS_FREE if name not in free}
        problem = self._problem(self._template(free), target, scale, material_with(self.base, held))
        start = problem.layout.to_unconstrained(problem.layout.join({**fitted, **held}))
        theta, cost, steps_, status, pinned, information = yield from polish_steps(
            problem, start, self.options, reject_ratio=STRICT_REJECT_RATIO
        )
        x = physical_values(pinned, theta)
        if not np.all(np.isfinite(x)):
            raise StraussFitError("the refit with the held parameters ended at non-finite parameters")
        model = np.asarray((yield render_at.call(pinned, x)))
        rss = float(cost) * scale**2
        return _Solution(problem, pinned, x, rss, int(steps_), status, information, model)

    def _decide(self, current: _Solution, sigma: float) -> Steps:
        """Which parameters the conversion image constrains at the solution ``current``:
        :func:`strauss_fit.fit.identifiability.numerical_decision` at the reference noise
        ``sigma`` with the Jacobian there, as a fit decides at its optimum. An entry pinned
        at a bound is protected from being held, as in a fit, where the data push against
        it — not where the cost is nearly flat there (the fit's ``flat-at-bound`` warning:
        free, its deviation would exceed :data:`strauss_fit.fit.diagnosis.WEAK_FRACTION` of
        its scale): then the bound, not the image, sets it. Returns the decision and the
        Jacobian."""
        layout = current.problem.layout
        jacobian = np.asarray((yield jacobian_kernel.call(current.problem, current.x)))
        pinned = np.asarray(current.pinned.pinned)
        at_bound = frozenset(
            name
            for name, size, offset in zip(layout.names, layout.sizes, layout.offsets)
            if size == 1 and pinned[offset]
        )
        scale = np.array([float(deviation_scale(owner, value)) for owner, value in zip(_owners(layout), current.x)])
        loose = deviations(covariance(information_of(jacobian), sigma**2)) > WEAK_FRACTION * scale
        flat = {owner for owner, is_loose in zip(_owners(layout), loose) if is_loose}
        decision = numerical_decision(layout, jacobian, current.x, sigma, self.options.threshold, at_bound - flat)
        return decision, jacobian

    def _black_strauss(self, entry: Entry, guess: dict, guess_notes: list[str], target: np.ndarray) -> dict[str, Any]:
        fitted = self._strauss_values(entry, guess)
        model = self.strauss_target(Material(**{**fitted, "transparency": 0.0}))
        return {
            "name": entry.name,
            "source": entry.source,
            "status": "ok",
            "input": {"phong": entry.material.to_dict(), "opacity": entry.opacity, "ior": entry.ior},
            "guess": guess,
            "strauss": fitted,
            "held": {},
            "uncertainty": None,
            "correlation": None,
            "solver": {"status": "not run", "steps": 0, "best_start": None, "starts": 0, "at_bound": []},
            "notes": list(entry.notes)
            + guess_notes
            + ["the material renders black in the conversion scene: nothing to fit, the closed-form guess is returned"],
            # measured here, against this material's own target (its exposure scale)
            "residual": _residual_stats(model, target),
        }

    # -- Strauss -> Phong ----------------------------------------------------------------

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
        template = dataclasses.replace(self.phong_template, blinn=blinn) if blinn else self.phong_template

        def prepare(i: int, entry: Entry) -> tuple:
            material = entry.build()
            opaque = Material(**{**material.to_dict(), "transparency": 0.0})
            guess, ka = phong_guess(opaque)
            if blinn:
                guess[6] = unit_from_exponent(4.0 * float(exponent_from_unit(guess[6])))
            return (i, entry, guess, ka, self._strauss_vector(opaque))

        return self._stream(
            entries, _Direction(prepare, lambda item: self._phong_steps(item, template)), progress, start
        )

    def _phong_starts(self, guess: np.ndarray) -> np.ndarray:
        """The guess, then the exponent ×4 and ÷4, then the highlight halved and the
        exponent ×16 (first :attr:`Settings.starts` of them)."""
        step = math.log(4.0) / math.log(MAX_EXPONENT)
        rows = [guess]
        for du, spec_factor in ((step, 1.0), (-step, 1.0), (2 * step, 0.5), (-2 * step, 2.0), (3 * step, 1.0)):
            row = guess.copy()
            row[6] = float(np.clip(row[6] + du, 0.0, 1.0))
            row[3:6] = np.clip(row[3:6] * spec_factor, 0.0, 1.0)
            rows.append(row)
        rows = rows[: max(self.settings.starts, 1)]
        return PHONG_LAYOUT.to_unconstrained(np.stack(rows), margin=START_MARGIN)

    def _phong_steps(self, item: tuple, template: Any) -> Steps:
        """The Strauss → Phong conversion of one material, as steps: every start solved
        to convergence (:data:`strauss_fit.convert.phong_fit.solve_starts`), the best
        kept, what the image constrains decided at it as a fit decides it."""
        _, entry, guess, ka, source = item
        # rendered here, batched with the chunk's other renders (see _strauss_steps)
        target = np.asarray((yield render_at.call(self.strauss, source)))
        if not np.all(np.isfinite(target)):
            raise StraussFitError("the Strauss rendering is not finite")
        if float(np.max(target)) <= BLACK_LEVEL:
            x = guess.copy()
            x[0:6] = 0.0  # Phong black: D = S = 0 (the exponent is the guess's, it shows nowhere)
            return (
                yield from self._phong_result(
                    entry,
                    guess,
                    ka,
                    template,
                    x,
                    target,
                    None,
                    None,
                    {"status": "not run", "steps": 0, "best_start": None, "starts": 0, "at_bound": []},
                    [
                        f"the material renders black in the conversion scene (largest value "
                        f"{float(np.max(target)):.2g}, below {BLACK_LEVEL:g}, an 8-bit image's first step): nothing "
                        "to fit, Phong black (kd = ks = 0) is returned"
                    ],
                    {},
                )
            )
        scale = _scale_of(target)
        problem = dataclasses.replace(
            template, target=np.asarray(target), residual_scale=np.asarray(scale), ambient_ka=np.asarray(ka)
        )
        thetas = self._phong_starts(guess)
        values, costs_, steps_, ok = (
            np.asarray(v)
            for v in (
                yield solve_phong_starts.call(
                    problem, thetas, self.settings.rtol, self.settings.atol, self.settings.max_steps, self.batched
                )
            )
        )
        finite = np.isfinite(costs_)
        if not finite.any():
            raise StraussFitError("every start of the fit diverged to non-finite values")
        best = int(np.argmin(np.where(finite, costs_, np.inf)))
        x = np.asarray(PHONG_LAYOUT.to_physical_numpy(values[best]))
        if not np.all(np.isfinite(x)):
            raise StraussFitError("the fit ended at non-finite parameters")
        rss = float(costs_[best]) * scale**2
        jacobian = np.asarray((yield jacobian_kernel.call(problem, x)))
        labels = PHONG_LAYOUT.labels()
        at_bound = [label for label, v in zip(labels, x) if v < 1e-6 or v > 1 - 1e-6]
        decision = numerical_decision(
            PHONG_LAYOUT, jacobian, x, reference_noise_level(target), self.options.threshold, frozenset(at_bound)
        )
        held = {
            name: {"value": float(x[labels.index(name)]), "reason": f"{reason}; held at the value the fit reached"}
            for name, reason in decision.held.items()
        }
        free = np.array([label not in held for label in labels])
        sd, corr = laplace_deviations_from(jacobian, rss, free)
        status = "successful" if bool(ok[best]) else "max_steps_reached"
        notes = []
        if status != "successful":
            notes.append(f"the solver ended with status '{status}'")
        for name, info in held.items():
            notes.append(f"{name} held at {info['value']:.4g}: {info['reason']}")
        bound = [label for label in at_bound if label not in held]
        if bound:
            notes.append(
                "at a bound, where the data push against it (its Laplace deviation is no symmetric interval there): "
                + ", ".join(bound)
            )
        solver = {
            "status": status,
            "steps": int(steps_[best]),
            "best_start": best,
            "starts": int(len(costs_)),
            "at_bound": bound,
        }
        return (yield from self._phong_result(entry, guess, ka, template, x, target, sd, corr, solver, notes, held))

    def _phong_result(
        self,
        entry: Entry,
        guess: np.ndarray,
        ka: float,
        template,
        x: np.ndarray,
        target: np.ndarray,
        sd: np.ndarray | None,
        corr: np.ndarray | None,
        solver: dict,
        notes: list[str],
        held: dict[str, Any],
    ) -> Steps:
        problem = dataclasses.replace(template, target=np.asarray(target), ambient_ka=np.asarray(ka))
        model = np.asarray((yield render_at.call(problem, x)))
        phong = _phong_dict(x, ka, template.blinn)
        uncertainty = None
        correlation = None
        if sd is not None:
            n = float(exponent_from_unit(x[6]))
            sd_or_none = [None if label in held else float(v) for label, v in zip(PHONG_LAYOUT.labels(), sd)]
            uncertainty = {
                "diffuse": sd_or_none[0:3],
                "specular": sd_or_none[3:6],
                "exponent": None if sd_or_none[6] is None else float(n * math.log(MAX_EXPONENT) * sd_or_none[6]),
            }
            correlation = {"labels": PHONG_LAYOUT.labels(), "matrix": np.round(corr, 6).tolist()}
        t = float(entry.material.transparency)
        all_notes = list(entry.notes) + notes
        if t > 0:
            all_notes.append(
                f"opacity d = 1 - t = {1 - t:.4g} carried over, not fitted (the fit matches the opaque appearance)"
            )
        all_notes.append(f"ka = (1 - s^3)·max(C) = {ka:.4g} so that Phong's ambient term equals Strauss's")
        lobe = self._lobe_note(phong["exponent"])
        if lobe:
            all_notes.append(lobe)
        return {
            "name": entry.name,
            "source": entry.source,
            "status": "ok",
            "input": {"strauss": entry.material.to_dict()},
            "guess": _phong_dict(guess, ka, template.blinn),
            "phong": phong,
            "opacity": float(1.0 - t),
            "ior": float(entry.material.ior),
            "held": held,
            "uncertainty": uncertainty,
            "correlation": correlation,
            "solver": solver,
            "notes": all_notes,
            # measured here, against this material's own target (its exposure scale)
            "residual": _residual_stats(model, target),
        }


@dataclass
class _Solution:
    """A Phong → Strauss fit: the problem (nothing pinned), the problem with the polish's
    pins, the physical optimum, RSS, steps, status, JᵀJ there (None: to be computed) and
    the rendered model at the pixels used."""

    problem: Any
    pinned: Any
    x: np.ndarray
    rss: float
    steps: int
    status: str
    information: np.ndarray | None
    model: np.ndarray


def _changed(values: dict[str, Any], fitted: dict[str, Any]) -> bool:
    """Whether any of ``values`` differs from the fitted value."""
    return any(
        not np.allclose(np.asarray(value, dtype=float), np.asarray(fitted[name], dtype=float))
        for name, value in values.items()
    )


def _owners(layout: Any) -> list[str]:
    """The parameter name of every entry of ``layout`` (``color`` three times)."""
    return [name for name, size in zip(layout.names, layout.sizes) for _ in range(size)]


def _value_text(value: Any) -> str:
    if isinstance(value, (list, tuple)):
        return "(" + ", ".join(f"{float(v):.4g}" for v in value) + ")"
    return f"{float(value):.4g}"


def _phong_dict(x: np.ndarray, ka: float, blinn: bool) -> dict[str, Any]:
    material = material_from_vector(jnp.asarray(x), ka, blinn)
    out = {
        name: (float(v) if np.ndim(v) == 0 else [float(c) for c in np.asarray(v)])
        for name, v in (
            ("ka", material.ka),
            ("kd", material.kd),
            ("ks", material.ks),
            ("exponent", material.exponent),
            ("diffuse_color", material.diffuse_color),
            ("specular_color", material.specular_color),
        )
    }
    out["exponent"] = float(min(out["exponent"], MAX_EXPONENT))
    out["blinn"] = bool(blinn)
    return out


def _message(exc: BaseException) -> str:
    if isinstance(exc, StraussFitError):
        return str(exc)
    text = str(exc).strip().splitlines()
    return f"unexpected {type(exc).__name__}: {text[0] if text else 'no message'}"


class _Reporter:
    """Counts finished materials and passes a one-line summary of each to ``progress``."""

    def __init__(self, progress: Progress | None, total: int, done: int = 0):
        self.progress, self.total, self.done = progress, total, done

    def __call__(self, entry: Entry, result: dict[str, Any]) -> dict[str, Any]:
        self.done += 1
        if self.progress is not None:
            self.progress(self.done, self.total, f"{entry.name}: {_summary(result)}")
        return result


def _summary(result: dict[str, Any]) -> str:
    if result["status"] != "ok":
        return f"error: {result['message']}"
    residual = result["residual"]
    return f"ok, RMS {residual['rms']:.3g}, ΔE2000 mean {residual['delta_e2000_mean']:.3g}"


# --- entry points ------------------------------------------------------------------------


def _entries(materials: Any, kind: type) -> list[Entry]:
    """Materials (one, or a sequence of materials or :class:`Entry` objects) as entries."""
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
    conversion scene (a :class:`~strauss_fit.scene.loading.Scene`, a scene file, or None
    for the default)."""
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
    and strauss-fit's version: :func:`~strauss_fit.io.journal.run_key`)."""
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
    ``.csv`` or ``.mtl`` files: :mod:`strauss_fit.io.material_tables`), convert them in
    ``direction`` (``phong2strauss`` or ``strauss2phong``) on the conversion scene
    (``scene``, at ``size`` pixels), write the results to ``output`` (``.json``, ``.csv``,
    or ``.mtl`` for Strauss → Phong) and return the document written (for JSON; the
    other formats hold its ``materials``). ``log`` receives progress lines, ``warn``
    warnings (inputs that are allowed but almost certainly not meant, materials renamed
    in a ``.mtl`` output).

    Results are appended to the progress file ``OUTPUT.partial``
    (:func:`progress_path`, :class:`strauss_fit.io.journal.Journal`) as they complete; the
    output is written atomically at the end and the progress file removed. After an
    interruption (Ctrl-C, a killed process, a full disk) ``resume`` continues from the
    progress file, with the same inputs and options, to the same output an
    uninterrupted run writes (its ``wall_time_s`` counts every run); without ``resume`` an
    existing progress file is refused unless ``force``."""
    if direction not in DIRECTIONS:
        raise StraussFitError(f"unknown conversion {direction!r}; expected one of {', '.join(DIRECTIONS)}")
    if resume and force:
        raise StraussFitError("--resume continues an interrupted conversion and --force starts again: give one")
    log = log or (lambda message: None)
    warn = warn or (lambda message: None)
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
    started = time.perf_counter()
    reader = read_phong_input if direction == "phong2strauss" else read_strauss_input
    entries, input_notes, description = reader(inputs)
    for note in input_notes:
        log(f"{direction}: note: {note}")
    for entry in entries:
        for warning in entry.warnings:
            warn(f"{entry.name}: {warning}")
    conversion = conversion_scene(scene, size)
    converter = Converter(
        conversion, settings, scene_label=str(scene) if scene else f"data_synth/scenes/{DEFAULT_SCENE_NAME}"
    )
    journal = Journal(partial, _run_key(direction, entries, converter, settings, blinn))
    results: list[dict[str, Any]] = []
    earlier_s = 0.0
    if resume:
        records = journal.open()
        if [r.get("index") for r in records] != list(range(len(records))) or len(records) > len(entries):
            raise StraussFitError(f"{partial} is damaged (its results are out of order); start again with --force")
        results = [r["result"] for r in records]
        earlier_s = float(records[-1].get("elapsed_s", 0.0)) if records else 0.0
        log(f"{direction}: resuming: {len(results)} of {len(entries)} material(s) done before")
    elif force:
        journal.remove()
    log(
        f"{direction}: {len(entries)} material(s) from {description}; preparing the conversion scene "
        f"({conversion.camera.width}x{conversion.camera.height})"
    )

    def progress(done: int, total: int, message: str) -> None:
        log(f"{direction}: [{done}/{total}] {message}")

    if direction == "phong2strauss":
        stream = converter.iter_phong_to_strauss(entries, progress, start=len(results))
    else:
        stream = converter.iter_strauss_to_phong(entries, progress, blinn=blinn, start=len(results))
    for index, result in stream:
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

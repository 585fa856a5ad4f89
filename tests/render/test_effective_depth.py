"""The global model traced only as deep as it can change the image (issue 24, item 6).

``render`` at ``depth = 64`` with a glass material once compiled 63 unrolled interior
interactions (70 s and 2.5 GB for the bundled glass scene). :func:`effective_depth` bounds
what the interactions beyond a depth can still add; these tests check the bound itself
(against the model's own weights), the depths it gives, that ``render`` compiles only that
depth, and that the image equals a deeper full render to within the stated tolerance.
No timing is asserted.
"""

from __future__ import annotations

import dataclasses
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import strauss_fit as sf
from strauss_fit.models.strauss import specular_color, specular_peak
from strauss_fit.rendering.strauss import (
    DEPTH_STEPS,
    OUTPUT_TOLERANCE,
    _mirror_terms,
    depth_messages,
    effective_depth,
    interior_reflectance_bound,
    transmission_weight,
    unit_roundoff,
)
from strauss_fit.rendering.strauss import render as render_function
from strauss_fit.scene.background import Background
from strauss_fit.scene.loading import background_peak
from support import SCENES

strauss = sys.modules[render_function.__module__]
F32, F64 = unit_roundoff(jnp.float32), unit_roundoff(jnp.float64)


def glass(depth: int, size: int = 16) -> sf.Scene:
    """The bundled glass sphere over a checkerboard (t = 0.9, s = 0.9, n = 1.5)."""
    scene = sf.load_scene(SCENES / "glass_checkerboard.toml").resized(size, size)
    return dataclasses.replace(scene, depth=depth)


def test_unit_roundoff():
    assert F32 == 2.0**-24 and F64 == 2.0**-53 and OUTPUT_TOLERANCE == F32


@pytest.mark.parametrize("t", [0.05, 0.5, 0.9, 1.0])
@pytest.mark.parametrize("s", [0.0, 0.5, 0.9, 1.0])
@pytest.mark.parametrize("m", [0.0, 1.0])
@pytest.mark.parametrize("n", [1.0, 1.2, 1.5, 2.4])
def test_reflectance_bound_holds_at_every_interior_angle(x64, t, s, m, n):
    """The bound of the proof: at every angle a refracted ray can meet the surface from
    inside (up to the critical angle), the weight kept inside, r_j C_s, is at most ρ, and
    kept plus leaving weight (r_j + z) is at most 1. ρ is also tight (within 10 %)."""
    material = sf.Material(color=(0.9, 0.5, 0.2), smoothness=s, metalness=m, transparency=t, ior=n)
    rho = interior_reflectance_bound(material)
    critical = np.arcsin(1.0 / n)
    angles = np.linspace(0.0, critical, 2001)
    j, f = _mirror_terms(jnp.asarray(np.cos(angles)))
    kept = specular_peak(material, j)
    per_channel = np.asarray(kept[:, None] * specular_color(material, f, jnp.ones(3)))
    assert np.all(per_channel <= rho + 1e-15)
    assert np.all(per_channel.max(axis=0) >= 0.9 * rho - 1e-12)
    assert np.all(np.asarray(kept + transmission_weight(material, kept)) <= 1 + 1e-12)


def test_effective_depth_of_the_bundled_glass(x64):
    """t C ρ^(D-1) <= tolerance: ρ = 0.0768 for the glass, so 2^-24 needs 7 interactions
    inside (depth 8) and 2^-53 needs 15 (depth 16); never deeper than the scene asks."""
    scene = glass(64)
    rho = interior_reflectance_bound(scene.material)
    assert np.allclose(rho, 0.07677, atol=1e-5)
    assert effective_depth(scene, tolerance=F32) == 8
    assert effective_depth(scene, tolerance=F64) == 16
    assert effective_depth(scene, tolerance=1e-4) == 6  # 5 interactions, rounded up to a step
    assert effective_depth(glass(4), tolerance=F32) == 4  # the bundled depth: unchanged
    assert effective_depth(glass(7), tolerance=F32) == 7  # a step above the scene's depth: its depth
    assert effective_depth(scene, tolerance=0.0) == 64  # no tolerance: the full depth
    for depth in (1, 2):
        assert effective_depth(glass(depth), tolerance=1.0) == depth
    # the chosen depth meets the bound, the one below does not
    t, color = 0.9, np.array([0.95, 0.97, 1.0])
    assert np.all(t * color * rho**7 <= F32) and not np.all(t * color * rho**6 <= F32)


def test_effective_depth_needs_two_without_transmission_or_background(x64):
    scene = glass(64)
    opaque = dataclasses.replace(scene.material, transparency=jnp.asarray(0.0))
    assert effective_depth(scene, opaque, tolerance=F64) == 2
    black = dataclasses.replace(scene, background=Background("color", jnp.zeros(3)))
    assert background_peak(black.background) == 0.0
    assert effective_depth(black, tolerance=F64) == 2


def test_slowly_decaying_material_keeps_its_depth_and_a_batch_takes_the_deepest(x64):
    scene = glass(64)
    mirror_glass = sf.Material(color=(1, 1, 1), smoothness=1.0, transparency=0.1)  # r_n = 0.9
    assert effective_depth(scene, mirror_glass, tolerance=F32) == 64
    assert effective_depth(scene, sf.Material(smoothness=0.9, transparency=0.1), tolerance=F32) == 48
    batch = jax.tree.map(lambda a, b: jnp.stack([a, b]), scene.material, mirror_glass)
    assert effective_depth(scene, batch, tolerance=F32) == 64


def test_traced_material_gets_the_full_depth(x64):
    scene = glass(64)
    seen = []

    def probe(material):
        seen.append(effective_depth(scene, material, tolerance=F32))
        return material.transparency

    jax.jit(probe)(scene.material)
    assert seen == [64]


def test_depth_steps_are_increasing_and_end_at_the_largest_depth():
    assert list(DEPTH_STEPS) == sorted(set(DEPTH_STEPS)) and DEPTH_STEPS[0] == 2 and DEPTH_STEPS[-1] == 64


def test_render_compiles_only_the_effective_depth(monkeypatch):
    """The compiled program is the small one: render() hands render_jit the reduced depth."""
    depths = []

    def spy(scene, *args):  # records what would be compiled, compiles nothing
        depths.append(scene.depth)
        return None, None

    monkeypatch.setattr(strauss, "render_jit", spy)
    sf.render(glass(64, size=4), depth_tolerance=F32)
    sf.render(glass(64, size=4), dtype=jnp.float32)  # default: float32's unit roundoff
    sf.render(glass(3, size=4), depth_tolerance=F32)  # already shallow: untouched
    assert depths == [8, 8, 3]


@pytest.mark.parametrize("tolerance", [1e-4, F32])
def test_huge_depth_gives_the_full_depth_image_within_the_tolerance(tolerance):
    """depth 64 (traced to 6 or 8) against a full depth-12 render, 16 × 16 pixels: within
    tolerance × the background's brightest radiance (0.9), plus float64 rounding."""
    reduced = np.asarray(sf.render(glass(64), depth_tolerance=tolerance)[0])
    full = np.asarray(sf.render(glass(12), depth_tolerance=0)[0])
    peak = background_peak(glass(12).background)
    assert peak == pytest.approx(0.9)
    difference = np.max(np.abs(reduced - full))
    assert difference <= tolerance * peak + 1e-15
    if tolerance == 1e-4:
        assert difference > 0  # (the comparison sees the cut: depth 6 is not depth 12)


def test_bundled_scenes_render_exactly_as_at_their_own_depth(scenes_dir):
    """No bundled scene is deep enough to be cut: every image is bit-identical to the full
    depth (render_jit called directly, as render() did before)."""
    for path in sorted(scenes_dir.glob("*.toml")):
        scene = sf.load_scene(path).resized(8, 8)
        image = np.asarray(sf.render(scene)[0])
        with sf.float64():
            plan = strauss.plan_render(scene, scene.material)
            full = np.asarray(strauss.render_jit(scene, scene.material, plan, "exact", 1024, jnp.dtype("float64"))[0])
        np.testing.assert_array_equal(image, full, err_msg=str(path))


def test_depth_messages(x64):
    """One line when the depth is reduced; a warning when what remains is slow to compile;
    nothing for the bundled scenes at their own depth."""
    (note,) = depth_messages(glass(64), tolerance=OUTPUT_TOLERANCE)
    assert note.startswith("depth 64 reduced to 8: ") and "6e-08" in note
    slow = sf.Material(smoothness=0.9, transparency=0.1)
    messages = depth_messages(glass(64), slow, tolerance=OUTPUT_TOLERANCE)
    assert len(messages) == 2 and messages[0].startswith("depth 64 reduced to 48")
    assert messages[1].startswith("warning: depth 48 is needed") and "about 40 s" in messages[1]
    assert depth_messages(glass(4), tolerance=OUTPUT_TOLERANCE) == []
    assert depth_messages(glass(64), sf.Material(), tolerance=OUTPUT_TOLERANCE) == []  # opaque
    assert all("\n" not in m for m in messages)

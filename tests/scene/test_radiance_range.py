"""The renderer's range (issue 24, item 13): a light or background bright enough to make
the rendered radiance overflow is refused when the scene is loaded (and by ``render`` for
scenes built in Python), in one line naming the light and its value, instead of rendering
infinities that are found only when the image is written."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import strauss_fit as sf
from strauss_fit.scene.loading import MAX_RADIANCE, RadianceRangeError, check_radiance_range, light_peaks


def directional(intensity, color=(1, 1, 1), direction=(0.3, 0.5, 1.0)):
    return {"kind": "directional", "direction": list(direction), "intensity": intensity, "color": list(color)}


def table(header, values):
    """A TOML table (Python's reprs of numbers and lists are TOML; strings get double quotes)."""
    return [header] + [f'{key} = "{value}"' if isinstance(value, str) else f"{key} = {value}" for key, value in values]


def scene_file(tmp_path, lights, background=None):
    """A scene file, 8 × 8 pixels, with these [[light]] tables (and [background])."""
    lines = ["[camera]", "width = 8", "height = 8"]
    for light in lights:
        lines += table("[[light]]", light.items())
    if background:
        lines += table("[background]", background.items())
    path = tmp_path / "bright.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize(
    "lights,background,pattern",
    [
        # the case: named, with its value and the range
        ([directional(1e308)], None, r"\[\[light\]\] #1: intensity 1e\+308 overflows the renderer's range"),
        (
            [{"kind": "ambient", "intensity": 0.1}, directional(1e31)],
            None,
            r"\[\[light\]\] #2: intensity 1e\+31 overflows the renderer's range: .* at most 1e\+30",
        ),
        ([directional(1e29, color=(100, 1, 1))], None, r"#1: peak irradiance intensity 1e\+29 × max\(1, color 100\)"),
        ([directional(1e-10, color=(1e31, 0, 0))], None, r"#1: color component 1e\+31 overflows"),
        # a point light just outside the sphere with inverse-square falloff
        (
            [{"kind": "point", "position": [1.000001, 0, 0], "intensity": 1e20, "attenuation": [0, 0, 1]}],
            None,
            r"#1: peak irradiance .* ÷ attenuation 1e-12 at the sphere's nearest point \(distance 1e-06\) = 1e\+32",
        ),
        (
            [{"kind": "ambient", "intensity": 6e29}, directional(1), {"kind": "ambient", "intensity": 6e29}],
            None,
            r"\[\[light\]\] #1, #3 \(ambient, added\): intensity 1.2e\+30 overflows",
        ),
        (
            [directional(6e29), directional(7e29, direction=(0, 1, 1))],
            None,
            r"add up to 1.3e\+30, more than the renderer's range \(1e\+30\); the largest: \[\[light\]\] #2 \(7e\+29\)",
        ),
        ([directional(1)], {"color": [1e31, 0, 0]}, r"\[background\]: radiance 1e\+31 overflows"),
        (
            [directional(1)],
            {"kind": "checkerboard", "colors": [[0, 0, 0], [0, 2e30, 0]]},
            r"\[background\]: radiance 2e\+30 overflows",
        ),
    ],
)
def test_too_bright_scenes_are_one_line_errors_naming_the_light(tmp_path, lights, background, pattern):
    path = scene_file(tmp_path, lights, background)
    with pytest.raises(RadianceRangeError, match=pattern) as info:
        sf.load_scene(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"{path}: ")
    assert isinstance(info.value, sf.SceneError) and isinstance(info.value, sf.StraussFitError)


def test_environment_image_times_scale_is_in_range(tmp_path):
    from strauss_fit.io.images import write_image

    write_image(tmp_path / "env.exr", np.full((4, 8, 3), 2.0, dtype=np.float32))
    path = scene_file(tmp_path, [directional(1)], {"kind": "environment", "image": "env.exr", "scale": 1e30})
    with pytest.raises(RadianceRangeError, match=r"\[background\]: radiance 2e\+30 overflows"):
        sf.load_scene(path)


def test_the_edge_of_the_range_renders_finite_in_float32(tmp_path):
    """What the range promises: a scene whose radiance scale is exactly 1e30 (a light, an
    ambient light and a bright checkerboard, seen through and reflected by glass) renders
    finite in float32, no pixel above 3e30; a point light at the limit too."""
    lights = [directional(4e29, color=(1, 0.5, 1)), {"kind": "ambient", "intensity": 1e29}]
    background = {"kind": "checkerboard", "colors": [[5e29, 1e29, 0], [0, 0, 2e29]], "color": [1e29, 1e29, 1e29]}
    path = scene_file(tmp_path, lights, background)
    with open(path, "a") as file:
        file.write("[material]\ntransparency = 0.9\nsmoothness = 0.9\nmetalness = 0.5\n[render]\ndepth = 4\n")
    scene = sf.load_scene(path)
    peaks = light_peaks(scene.lights)
    assert sum(p.peak for p in peaks) + 5e29 == pytest.approx(MAX_RADIANCE)
    for dtype in (jnp.float32, jnp.float64):
        image = np.asarray(sf.render(scene, dtype=dtype)[0])
        assert np.all(np.isfinite(image)) and image.max() <= 3 * MAX_RADIANCE and image.max() > 1e29
    near = [{"kind": "point", "position": [0.0, 0.0, 1.001], "intensity": 0.99e24, "attenuation": [0, 0, 1]}]
    scene = sf.load_scene(scene_file(tmp_path, near))
    assert light_peaks(scene.lights)[0].peak == pytest.approx(0.99e30, rel=1e-6)
    image = np.asarray(sf.render(scene, dtype=jnp.float32)[0])
    assert np.all(np.isfinite(image))


def test_render_refuses_a_scene_built_in_python(key_and_fill):
    bright = dataclasses.replace(
        key_and_fill, lights=key_and_fill.lights.with_intensities({"directional": [1e308, 0.5]})
    )
    with pytest.raises(RadianceRangeError, match=r"^scene: directional light #1: intensity 1e\+308 overflows"):
        sf.render(bright)
    with pytest.raises(RadianceRangeError, match="directional light #1"):
        check_radiance_range(bright)
    check_radiance_range(key_and_fill)  # the bundled scene is in range


def test_traced_intensities_are_not_checked(key_and_fill):
    """Inside jax.grad the intensities are not known: nothing is checked, the gradient flows."""

    def total(scale):
        lights = key_and_fill.lights.with_intensities({"directional": scale * jnp.array([1.0, 0.5])})
        return jnp.sum(sf.render(dataclasses.replace(key_and_fill, lights=lights))[0])

    with sf.float64():
        gradient = jax.grad(total)(1.0)
    assert np.isfinite(float(gradient)) and float(gradient) > 0


def test_bundled_scenes_are_in_range(scenes_dir):
    for path in sorted(scenes_dir.glob("*.toml")):
        scene = sf.load_scene(path)  # would raise
        assert sum(p.peak for p in light_peaks(scene.lights)) < 100, path

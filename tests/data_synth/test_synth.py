"""data_synth: sampling, sidecars, sensor noise, clip masks, reproducibility, interruption
and resumption, the bundled dataset (``strauss-fit synth`` end to end:
tests/cli/test_cli_synth.py)."""

import json
import math
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

import data_synth
import data_synth.files
from data_synth import Sensor, encode_ldr, generate, load_sample, load_spec, parse_spec, plan_samples, read_index
from data_synth.generate import render_clean, render_model
from data_synth.params import SpecError
from strauss_fit.io.images import read_image
from support import SCENES, files_of
from support import SYNTH_TOTAL as TOTAL


def read_codes(path: Path) -> np.ndarray:
    image = oiio.ImageInput.open(str(path))
    codes = image.read_image(0, 0, 0, image.spec().nchannels, "uint8")
    image.close()
    return np.asarray(codes)


# --- sampling ---------------------------------------------------------------------------


def test_grid_is_the_cartesian_product_in_parameter_order(tmp_path):
    spec = parse_spec(
        {
            "seed": 1,
            "group": [
                {
                    "name": "g",
                    "model": "strauss",
                    "scenes": [str(SCENES / "key_light.toml")],
                    "parameters": {
                        "smoothness": {"low": 0.0, "high": 1.0, "steps": 3},
                        "metalness": [0.0, 1.0],
                        "color": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                    },
                }
            ],
        }
    )
    samples = plan_samples(spec)
    assert len(samples) == 12
    combos = [(tuple(s.parameters["color"]), s.parameters["smoothness"], s.parameters["metalness"]) for s in samples]
    assert combos[:4] == [
        ((1.0, 0.0, 0.0), 0.0, 0.0),
        ((1.0, 0.0, 0.0), 0.0, 1.0),
        ((1.0, 0.0, 0.0), 0.5, 0.0),
        ((1.0, 0.0, 0.0), 0.5, 1.0),
    ]
    assert all(s.parameters["transparency"] == 0.0 and s.parameters["ior"] == 1.5 for s in samples)
    assert [s.id for s in samples[:2]] == ["g-0000", "g-0001"]


def test_random_draws_include_the_extremes_and_follow_the_seed():
    def spec(seed):
        return parse_spec(
            {
                "seed": seed,
                "group": [
                    {
                        "name": "r",
                        "model": "strauss",
                        "scenes": [str(SCENES / "key_light.toml")],
                        "sampling": "random",
                        "count": 5,
                        "parameters": {
                            "smoothness": {"low": 0.0, "high": 1.0},
                            "metalness": {"low": 0.0, "high": 1.0},
                            "transparency": {"low": 0.0, "high": 1.0},
                            "ior": {"low": 1.0, "high": 2.5},
                            "color": {"low": 0.0, "high": 1.0},
                        },
                    }
                ],
            }
        )

    samples = plan_samples(spec(3))
    assert len(samples) == 8 + 5
    corners = {
        (s.parameters["smoothness"], s.parameters["metalness"], s.parameters["transparency"]) for s in samples[:8]
    }
    assert corners == {(a, b, c) for a in (0.0, 1.0) for b in (0.0, 1.0) for c in (0.0, 1.0)}
    for s in samples:
        assert 1.0 <= s.parameters["ior"] <= 2.5 and all(0 <= c <= 1 for c in s.parameters["color"])
        assert all(type(v) is float for k, v in s.parameters.items() if k != "color")
    assert [s.parameters for s in plan_samples(spec(3))] == [s.parameters for s in samples]
    assert [s.parameters for s in plan_samples(spec(4))] != [s.parameters for s in samples]


def test_phong_axes_log_ranges_and_rgb_coefficients():
    spec = parse_spec(
        {
            "seed": 0,
            "group": [
                {
                    "name": "ph",
                    "model": "phong",
                    "scenes": [str(SCENES / "key_light.toml")],
                    "sampling": "random",
                    "count": 50,
                    "parameters": {
                        "exponent": {"low": 2.0, "high": 2000.0, "scale": "log"},
                        "ka": [0.1, 0.2, 0.3],
                        "ks": {"values": [0.5, [0.1, 0.2, 0.3]]},
                        "blinn": True,
                    },
                }
            ],
        }
    )
    samples = plan_samples(spec)
    exponents = np.array([s.parameters["exponent"] for s in samples])
    assert np.all((exponents >= 2.0) & (exponents <= 2000.0))
    assert np.median(exponents) < 200  # log-uniform: median near sqrt(2 * 2000) = 63
    assert all(s.parameters["ka"] == [0.1, 0.2, 0.3] and s.parameters["blinn"] is True for s in samples)
    assert {json.dumps(s.parameters["ks"]) for s in samples} == {"0.5", "[0.1, 0.2, 0.3]"}


# --- sidecars and index -----------------------------------------------------------------


def test_sidecars_round_trip_to_the_exact_parameters(reference):
    spec_path, out = reference
    plans = plan_samples(load_spec(spec_path))
    index = read_index(out)
    assert index["total"] == index["complete"] == TOTAL and index["pending"] == []
    assert [e["id"] for e in index["samples"]] == [p.id for p in plans]
    for plan in plans:
        text = (out / f"{plan.id}.json").read_text()
        sidecar = json.loads(text)
        assert sidecar["parameters"] == plan.parameters  # bit-exact floats (repr precision)
        assert sidecar["model"] == plan.model and sidecar["seed"] == {"entropy": 7, "spawn_key": list(plan.spawn_key)}
        sample = load_sample(out / f"{plan.id}.json")
        assert sample.material.to_dict() == plan.parameters
        if plan.model == "phong":
            # noise-free: the EXR is exactly the float32 rendering of the sidecar's scene and material
            image, _ = render_model("phong", sample.scene, sample.material)
            np.testing.assert_array_equal(read_image(sample.files["exr"]).pixels, image.astype(np.float32))
        else:
            assert sidecar["sensor"] == {"exposure": 2.0, "gain": 500.0, "read_noise": 0.01}
            assert set(sidecar["files"]) == {"exr", "png", "clip_mask"}
    assert "0.30000000000000004" in (out / "p-0000.json").read_text()


# --- the sensor -------------------------------------------------------------------------


@pytest.mark.parametrize(
    "sensor",
    [
        Sensor(exposure=2.0, gain=200.0),
        Sensor(exposure=1.0, read_noise=0.05),
        Sensor(exposure=0.5, gain=50.0, read_noise=0.02),
    ],
)
def test_noise_mean_and_variance_match_the_model(sensor):
    radiance = np.full((200, 200, 3), 0.4)
    observed = sensor.apply(radiance, np.random.default_rng(11))
    n = observed.size
    exposed = 0.4 * sensor.exposure
    var = float(sensor.expected_variance(exposed))
    assert var == pytest.approx((exposed / sensor.gain if sensor.gain else 0.0) + sensor.read_noise**2)
    # mean: standard error sqrt(var/n); variance: sd of the sample variance
    # sqrt(var^2 (2/(n-1) + kurtosis/n)), the Poisson part adding excess kurtosis 1/lambda
    assert abs(observed.mean() - exposed) < 5 * math.sqrt(var / n)
    shot = exposed / sensor.gain if sensor.gain else 0.0
    excess_fourth = shot**2 / (exposed * sensor.gain) if sensor.gain else 0.0
    sd_var = math.sqrt(2 * var**2 / (n - 1) + excess_fourth / n)
    assert abs(observed.var(ddof=1) - var) < 5 * sd_var
    # and the noise really is there (a test that can fail)
    assert observed.var() > 0.5 * var


def test_noise_free_sensor_is_exposure_only():
    radiance = np.random.default_rng(0).random((4, 5, 3))
    np.testing.assert_array_equal(Sensor(exposure=3.0).apply(radiance, np.random.default_rng(0)), radiance * 3.0)


def test_generated_noise_matches_the_model(reference):
    """End to end: (O - kL) / sqrt(kL/g + sigma^2) over the noisy group is standard."""
    spec_path, out = reference
    z = []
    for plan in plan_samples(load_spec(spec_path)):
        if plan.group.name != "s":
            continue
        clean, _ = render_clean(plan)
        sensor = plan.group.sensor
        exposed = sensor.exposure * clean
        observed = read_image(out / f"{plan.id}.exr").pixels
        z.append(((observed - exposed) / np.sqrt(sensor.expected_variance(exposed))).ravel())
    z = np.concatenate(z)
    n = z.size
    assert abs(z.mean()) < 5 / math.sqrt(n)
    assert abs(z.var(ddof=1) - 1) < 5 * math.sqrt(2 / n) + 0.02


def test_sensor_values_are_validated():
    with pytest.raises(SpecError, match=r"sensor exposure = 0 must be > 0"):
        Sensor(exposure=0)
    with pytest.raises(SpecError, match=r"sensor read_noise = -1 must be >= 0"):
        Sensor(read_noise=-1)
    with pytest.raises(SpecError, match=r"unknown sensor key\(s\) iso"):
        Sensor.from_dict({"iso": 100})


# --- LDR clipping -----------------------------------------------------------------------


def test_clip_mask_is_exactly_the_pixels_at_code_255(reference):
    _, out = reference
    total_clipped = 0
    for sidecar_path in sorted(out.glob("s-*.json")):
        sidecar = json.loads(sidecar_path.read_text())
        codes = read_codes(out / sidecar["files"]["png"])
        mask = read_codes(out / sidecar["files"]["clip_mask"])
        assert codes.shape == (16, 16, 3) and codes.dtype == np.uint8 and mask.shape == (16, 16, 1)
        assert set(np.unique(mask)) <= {0, 255}
        clipped = np.any(codes == 255, axis=-1)
        np.testing.assert_array_equal(mask[..., 0] == 255, clipped)
        assert sidecar["image"]["clipped_pixels"] == int(clipped.sum())
        np.testing.assert_array_equal(read_image(out / sidecar["files"]["png"]).clipped, clipped)
        # the PNG is the sRGB encoding of the same observation as the EXR (float32 there)
        hdr = read_image(out / sidecar["files"]["exr"]).pixels
        assert np.max(np.abs(encode_ldr(hdr)[0].astype(int) - codes.astype(int))) <= 1
        total_clipped += int(clipped.sum())
    assert 0 < total_clipped < 5 * 16 * 16  # some, not all: exposure 2 saturates the highlights


def test_encode_ldr_marks_only_saturated_codes():
    image = np.array(
        [
            [
                [0.2, 0.2, 0.2],
                [1.0, 0.0, 0.0],
                [0.999, 0.999, 0.999],
                [-0.5, 2.0, 0.5],
                [0.99, 0.99, 0.99],
                [-1.0, -1.0, -1.0],
            ]
        ]
    )
    codes, clipped = encode_ldr(image)
    assert codes[0, 1].tolist() == [255, 0, 0] and codes[0, 5].tolist() == [0, 0, 0]
    assert clipped.tolist() == [[False, True, True, True, False, False]]  # 0.999 rounds to 255; 0.99 to 254


# --- reproducibility, interruption, resumption ------------------------------------------


def test_same_seed_gives_byte_identical_files(tmp_path, reference):
    spec_path, out = reference
    again = tmp_path / "again"
    generate(load_spec(spec_path), again)
    assert files_of(again) == files_of(out)
    other = tmp_path / "other"
    generate(load_spec(spec_path, seed=8), other)
    assert files_of(other)["s-0004.exr"] != files_of(out)["s-0004.exr"]
    assert read_index(other)["seed"] == 8
    # no timestamp in the EXR header (OpenImageIO adds one by default): same bytes at any time
    image = oiio.ImageInput.open(str(out / "p-0000.exr"))
    attributes = {a.name for a in image.spec().extra_attribs}
    image.close()
    assert "DateTime" not in attributes and "compression" in attributes


def test_interrupted_run_resumes_to_the_same_files(tmp_path, reference):
    spec_path, out = reference
    spec = load_spec(spec_path)
    folder = tmp_path / "interrupted"

    def stop_after_three(progress):
        if progress.done == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        generate(spec, folder, progress=stop_after_three)
    index = read_index(folder)
    assert index["complete"] == 3 and [e["id"] for e in index["samples"]] == ["s-0000", "s-0001", "s-0002"]
    assert len(index["pending"]) == TOTAL - 3
    (folder / "s-0003.exr").write_bytes(b"half a file")  # a sample caught mid-write
    report = generate(spec, folder, resume=True)
    assert (report.skipped, report.written) == (3, TOTAL - 3)
    assert files_of(folder) == files_of(out)


# --- bad input --------------------------------------------------------------------------


# --- the bundled dataset ----------------------------------------------------------------


def test_bundled_dataset_is_complete_small_and_covers_the_issue():
    folder = data_synth.BUNDLED
    index = read_index(folder)
    assert index["complete"] == index["total"] >= 24 and index["pending"] == []
    size = sum(p.stat().st_size for p in folder.iterdir())
    assert size < 2_000_000
    roles, models, noisy, extremes = set(), set(), set(), set()
    for entry in index["samples"]:
        for name, digest in entry["sha256"].items():
            assert data_synth.files.sha256(folder / name) == digest, name
        sidecar = json.loads((folder / entry["files"]["sidecar"]).read_text())
        assert sidecar["parameters"] == entry["parameters"]
        assert (sidecar["image"]["width"], sidecar["image"]["height"]) == (64, 64)
        roles |= set(entry["files"])
        models.add(entry["model"])
        noisy.add(Sensor(**sidecar["sensor"]).noisy)
        if entry["model"] == "strauss":
            p = entry["parameters"]
            extremes |= {(k, p[k]) for k in ("smoothness", "metalness", "transparency") if p[k] in (0.0, 1.0)}
    assert models == {"strauss", "phong"} and noisy == {True, False}
    assert {"exr", "png", "clip_mask", "sidecar"} <= roles
    assert extremes == {(k, v) for k in ("smoothness", "metalness", "transparency") for v in (0.0, 1.0)}


def test_bundled_noise_free_samples_match_the_renderers():
    folder = data_synth.BUNDLED
    index = read_index(folder)
    checked = 0
    for entry in index["samples"]:
        sample = load_sample(folder / entry["files"]["sidecar"])
        if Sensor(**sample.sidecar["sensor"]).noisy or entry["group"] not in ("strauss-extremes", "phong-grid"):
            continue
        if entry["model"] == "strauss" and entry["parameters"]["transparency"] != 0.0:
            continue  # keep the test fast: one compiled variant per model
        image, _ = render_model(entry["model"], sample.scene, sample.material)
        if "exr" in sample.files:
            np.testing.assert_allclose(read_image(sample.files["exr"]).pixels, image, rtol=1e-6, atol=1e-6)
        if "png" in sample.files:
            codes = read_codes(sample.files["png"])
            assert np.max(np.abs(codes.astype(int) - encode_ldr(image)[0].astype(int))) <= 1
        checked += 1
    assert checked >= 8

"""The bundled Mitsuba 3 targets and their generator (``data_synth.make_bundled_mitsuba``).

Without Mitsuba: the bundled ``index.json`` and sidecars agree with the generator's case list
(ids, BSDFs, scenes, seeds, render settings, scene translation), so that neither can change
without the other; ``load_sample`` reads a bundled sample; the generator's errors are one
line and touch nothing. With Mitsuba: a regenerated sample equals the bundled one (the same
bytes with the bundled variant and Mitsuba version, else within the recorded noise).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from data_synth import BUNDLED_MITSUBA, load_sample, read_index
from data_synth import make_bundled_mitsuba as gen
from data_synth import mitsuba_backend as mb
from strauss_fit.errors import StraussFitError

SIDECAR_KEYS = [
    "format",
    "version",
    "id",
    "group",
    "index",
    "model",
    "parameters",
    "scene",
    "sensor",
    "formats",
    "seed",
    "render",
    "noise",
    "image",
    "files",
]


def _sidecar(entry: dict) -> dict:
    return json.loads((BUNDLED_MITSUBA / entry["files"]["sidecar"]).read_text(encoding="utf-8"))


def _without_environment_path(translation: dict) -> dict:
    translation = json.loads(json.dumps(translation))
    translation["background"].pop("image", None)
    return translation


def _key_paths(value, prefix: str = "") -> list[str]:
    """Every key path of a JSON value (list items of dicts included), in order."""
    if isinstance(value, dict):
        return [p for k, v in value.items() for p in [f"{prefix}.{k}", *_key_paths(v, f"{prefix}.{k}")]]
    if isinstance(value, list):
        return [p for i, v in enumerate(value) for p in _key_paths(v, f"{prefix}[{i}]")]
    return []


def test_bundled_index_matches_the_generator_case_list():
    index = read_index(BUNDLED_MITSUBA)
    samples = gen.plan()
    assert [s.id for s in samples] == [e["id"] for e in index["samples"]]
    assert index["total"] == index["complete"] == len(samples) == 13 and index["pending"] == []
    assert (index["spec"], index["description"], index["seed"]) == (gen.SPEC_NAME, gen.DESCRIPTION, gen.SEED)
    for sample, entry in zip(samples, index["samples"], strict=True):
        assert entry["group"] == sample.group and entry["model"] == "mitsuba", sample.id
        assert entry["scene"] == sample.scene_name and entry["parameters"] == sample.bsdf, sample.id
        assert entry["files"] == gen.sample_files(sample), sample.id
        sidecar = _sidecar(entry)
        described = gen.describe(sample, gen.VARIANT)
        assert {k: sidecar[k] for k in described if k != "render"} == {
            k: v for k, v in described.items() if k != "render"
        }, sample.id
        render = sidecar["render"]
        assert {k: render[k] for k in described["render"]} == described["render"], sample.id
        assert render["seeds"] == list(sample.seeds), sample.id
        assert (render["max_depth"], render["rr_depth"]) == (mb.DEFAULT_MAX_DEPTH, mb.DEFAULT_RR_DEPTH)
        assert list(sidecar) == SIDECAR_KEYS + (["reference"] if gen.body_bsdf(sample.bsdf) else []), sample.id
        if "reference" in sidecar:
            assert sidecar["reference"]["how"] == gen.REFERENCE_HOW
        assert sidecar["noise"]["method"] == gen.NOISE_METHOD
        assert sidecar["image"]["exr"]["compression"] == gen.IMAGE_COMPRESSION
        # the backend still translates the scene as it did when the set was rendered
        translation = mb.translate_scene(sample.definition, gen.SCENE_DIR).to_dict()
        assert _without_environment_path(render["translation"]) == _without_environment_path(translation), sample.id


def test_case_list_is_well_formed():
    samples = gen.plan()
    assert len({s.id for s in samples}) == len(samples)
    assert len({s.seeds for s in samples}) == len(samples)
    for sample in samples:
        assert gen.seeds(sample.spawn_key) == sample.seeds
        assert (gen.SCENE_DIR / f"{sample.scene_name}.toml").is_file()
        assert (gen.OUTPUT / sample.scene_file).resolve() == (gen.SCENE_DIR / f"{sample.scene_name}.toml").resolve()
    # the body whose albedo is the reference: specular reflection off, nothing else changed
    plastic = next(s.bsdf for s in samples if s.bsdf["type"] == "roughplastic")
    assert gen.body_bsdf(plastic) == {**plastic, "specular_reflectance": 0.0}
    assert gen.body_bsdf({"type": "roughconductor", "material": "Au"}) is None
    assert gen.body_bsdf(mb.validate_bsdf({"type": "principled", "metallic": 1.0})) is None


def test_load_sample_reads_a_bundled_mitsuba_sample():
    sample = load_sample(BUNDLED_MITSUBA / "mitsuba-roughplastic-blue-0000.json")
    assert sample.material is None
    assert sample.sidecar["model"] == "mitsuba" and sample.sidecar["format"] == "strauss-fit synth sample"
    assert sample.sidecar["parameters"]["type"] == "roughplastic"
    assert set(sample.files) == {"exr", "coverage", "mask"} and all(p.is_file() for p in sample.files.values())
    assert (sample.scene.camera.width, sample.scene.camera.height) == (64, 64)
    # an environment map named relative to the sidecar's folder resolves
    studio = load_sample(BUNDLED_MITSUBA / "mitsuba-conductor-studio-0000.json")
    assert studio.material is None and studio.scene.camera.width == 64


def test_load_sample_refuses_a_bad_mitsuba_sidecar(tmp_path):
    sidecar = json.loads((BUNDLED_MITSUBA / "mitsuba-diffuse-0000.json").read_text(encoding="utf-8"))
    sidecar["parameters"] = {"type": "diffuse", "reflectance": 2.0}
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(sidecar), encoding="utf-8")
    with pytest.raises(StraussFitError, match="reflectance must be in"):
        load_sample(path)
    sidecar["model"] = "pbrt"
    path.write_text(json.dumps(sidecar), encoding="utf-8")
    with pytest.raises(StraussFitError, match="is not a strauss-fit synth sample sidecar"):
        load_sample(path)


def test_generator_without_mitsuba_is_a_one_line_error(tmp_path, monkeypatch, capsys):
    def unavailable(variant):
        raise mb.MitsubaUnavailableError("Mitsuba 3 is not installed; install it with pip install -e '.[mitsuba]'")

    monkeypatch.setattr(mb, "_mitsuba", unavailable)
    out = tmp_path / "set"
    assert gen.main(["--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Mitsuba 3 is not installed" in err
    assert not out.exists()


def test_generator_option_errors(tmp_path, capsys):
    assert gen.main(["--out", str(tmp_path), "--only", "mitsuba-nothing-0000"]) == 2
    assert "unknown sample id(s) mitsuba-nothing-0000" in capsys.readouterr().err
    assert gen.main(["--out", str(tmp_path), "--only", "mitsuba-diffuse-0000", "--force"]) == 2
    assert "--only cannot be combined with --force" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_regenerated_sample_matches_the_bundled_one(tmp_path):
    """The generator reproduces a bundled sample: the same bytes with the bundled variant
    and Mitsuba version (the sidecar then differs only in the render times), else an image
    within the recorded Monte Carlo noise."""
    mi = pytest.importorskip("mitsuba")
    sid = "mitsuba-diffuse-0000"
    out = tmp_path / "set"
    index = gen.make_bundled(out, only=[sid])
    assert index["complete"] == 1 and len(index["pending"]) == 12
    assert read_index(out)["samples"] == index["samples"]
    entry = index["samples"][0]
    bundled = next(e for e in read_index(BUNDLED_MITSUBA)["samples"] if e["id"] == sid)
    old = _sidecar(bundled)
    new = json.loads((out / entry["files"]["sidecar"]).read_text(encoding="utf-8"))
    assert _key_paths(new) == _key_paths(old)
    same_renderer = (
        new["render"]["variant"] == old["render"]["variant"] and mi.__version__ == old["render"]["mitsuba_version"]
    )
    for role in ("coverage", "mask"):  # computed without Mitsuba
        assert entry["sha256"][entry["files"][role]] == bundled["sha256"][bundled["files"][role]]
    if same_renderer:
        assert entry["sha256"][f"{sid}.exr"] == bundled["sha256"][f"{sid}.exr"]
        for sidecar in (old, new):
            del sidecar["render"]["seconds"]
        assert new == old
    else:
        from strauss_fit import read_image

        full = read_image(out / f"{sid}.coverage.exr").pixels[..., 0] >= 1
        diff = (read_image(out / f"{sid}.exr").pixels - read_image(BUNDLED_MITSUBA / f"{sid}.exr").pixels)[full]
        noise = np.hypot(new["noise"]["per_channel"], old["noise"]["per_channel"])  # of the difference
        assert np.all(np.abs(diff.mean(axis=0)) < noise) and np.all(diff.std(axis=0) < 3 * noise)
        np.testing.assert_allclose(new["reference"]["diffuse_albedo"], old["reference"]["diffuse_albedo"], atol=2e-3)

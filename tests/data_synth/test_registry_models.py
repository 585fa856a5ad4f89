"""data_synth and the registry of reflectance models: every registry model but Phong is a
synth model, with the registry's parameters and ranges, rendered by
:func:`strauss_fit.rendering.reflectance.render_model`; ``"strauss"`` and ``"phong"`` produce
exactly the files they did before the table was built from the registry."""

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from data_synth import generate, load_sample, parse_spec, plan_samples, read_index, render_clean
from data_synth.generate import RENDER_METHODS, render_model
from data_synth.params import CLASSIC_MODELS, MODELS, REFLECTANCE_SYNTH_MODELS, SpecError
from data_synth.plan import plan_digest
from strauss_fit.errors import StraussFitError
from strauss_fit.io.images import read_image
from strauss_fit.models.reflectance import REFLECTANCE_MODELS
from strauss_fit.rendering.reflectance import render_model as render_reflectance

INTENSITY = 1.5
AMBIENT = 0.1
BACKGROUND = [0.1, 0.2, 0.3]
#: Directions toward the light: along the view (N = L = V = H at the centre pixel) and tilted (cos θ = 0.8 there).
LIGHTS = {"head_on": [0.0, 0.0, 1.0], "tilted": [0.0, 0.6, 0.8]}


def scene_text(direction: list[float], ambient: float) -> str:
    """An orthographic 15 × 15 scene (odd: the centre pixel sees the sphere's pole, N = (0, 0, 1))."""
    text = f"""[camera]
projection = "orthographic"
width = 15
height = 15

[[light]]
kind = "directional"
direction = {direction}
intensity = {INTENSITY}

[background]
color = {BACKGROUND}
"""
    if ambient:
        text += f'\n[[light]]\nkind = "ambient"\nintensity = {ambient}\n'
    return text


def write_scenes(folder: Path) -> None:
    (folder / "head_on.toml").write_text(scene_text(LIGHTS["head_on"], 0.0))
    (folder / "tilted.toml").write_text(scene_text(LIGHTS["tilted"], AMBIENT))


def group(name: str, model: str, parameters: dict, **more) -> dict:
    return {"name": name, "model": model, "scenes": ["head_on.toml", "tilted.toml"], "parameters": parameters, **more}


# --- the table --------------------------------------------------------------------------


def test_every_registry_model_but_phong_is_a_synth_model_with_the_registry_parameters():
    assert CLASSIC_MODELS == ("strauss", "phong")
    assert set(REFLECTANCE_SYNTH_MODELS) == set(REFLECTANCE_MODELS) - {"strauss", "phong"}
    assert {"lambert", "blinn-phong", "cook-torrance"} <= set(REFLECTANCE_SYNTH_MODELS)
    assert list(MODELS) == ["strauss", "phong", *REFLECTANCE_SYNTH_MODELS]
    assert list(RENDER_METHODS) == list(MODELS)
    for name in ("strauss", *REFLECTANCE_SYNTH_MODELS):
        registry = REFLECTANCE_MODELS[name].parameters
        assert MODELS[name].names == tuple(p.name for p in registry)
        for ours, theirs in zip(MODELS[name].parameters, registry):
            assert ours.shape == {1: "scalar", 3: "rgb"}[theirs.size]
            assert (ours.low, ours.high) == (theirs.low, theirs.high)
            default = np.broadcast_to(np.asarray(theirs.default, dtype=float), (theirs.size,)).tolist()
            assert ours.default == (default if theirs.size == 3 else default[0])
    # Strauss as it always was: its defaults, ranges and default extremes
    strauss = MODELS["strauss"]
    assert [(p.name, p.shape, p.default, p.low, p.high) for p in strauss.parameters] == [
        ("color", "rgb", [1.0, 1.0, 1.0], 0.0, 1.0),
        ("smoothness", "scalar", 0.5, 0.0, 1.0),
        ("metalness", "scalar", 0.0, 0.0, 1.0),
        ("transparency", "scalar", 0.0, 0.0, 1.0),
        ("ior", "scalar", 1.5, 1.0, None),
    ]
    assert strauss.default_extremes == ("smoothness", "metalness", "transparency")
    # "phong" is the classic material, not the registry's (diffuse, specular, exponent)
    assert MODELS["phong"].names == ("ka", "kd", "ks", "exponent", "diffuse_color", "specular_color", "blinn")
    assert all(MODELS[n].default_extremes == () for n in REFLECTANCE_SYNTH_MODELS)


def test_registry_defaults_fill_the_parameters_left_out(tmp_path):
    write_scenes(tmp_path)
    spec = parse_spec({"group": [group("ct", "cook-torrance", {"roughness": 0.4})]}, base_dir=tmp_path)
    parameters = plan_samples(spec)[0].parameters
    assert parameters == {"kd": [0.5, 0.5, 0.5], "f0": [0.04, 0.04, 0.04], "roughness": 0.4}
    assert all(type(c) is float for c in parameters["kd"] + parameters["f0"])


# --- rendering --------------------------------------------------------------------------


def test_lambert_and_cook_torrance_datasets_match_render_model_and_hand_values(tmp_path):
    write_scenes(tmp_path)
    spec = parse_spec(
        {
            "seed": 3,
            "group": [
                group("la", "lambert", {"albedo": [[0.2, 0.5, 0.8], [0.9, 0.1, 0.4]]}, formats=["exr", "png"]),
                group("ct", "cook-torrance", {"kd": [0.3, 0.2, 0.1], "f0": [0.04, 0.5, 0.9], "roughness": [0.2, 0.5]}),
            ],
        },
        source="spec.toml",
        base_dir=tmp_path,
    )
    out = tmp_path / "out"
    report = generate(spec, out)
    assert report.finished and report.written == 8
    centre = (7, 7)
    checked = set()
    for plan in plan_samples(spec):
        values, scene = plan.parameters, plan.scene.scene
        direct, mask = (np.asarray(a) for a in render_reflectance(scene, plan.model, values))
        clean, clean_mask = render_clean(plan)
        np.testing.assert_array_equal(clean, direct)
        np.testing.assert_array_equal(clean_mask, mask)
        stored = read_image(out / f"{plan.id}.exr").pixels
        np.testing.assert_array_equal(stored, direct.astype(np.float32))  # noise-free sensor: the radiance itself

        sidecar = json.loads((out / f"{plan.id}.json").read_text())
        assert sidecar["model"] == plan.model and sidecar["parameters"] == values
        assert sidecar["format"] == "strauss-fit synth sample" and sidecar["image"]["sphere_pixels"] == int(mask.sum())
        sample = load_sample(out / f"{plan.id}.json")
        assert sample.material == values
        np.testing.assert_array_equal(render_model(plan.model, sample.scene, sample.material)[0], direct)

        np.testing.assert_array_equal(direct[0, 0], BACKGROUND)
        light = LIGHTS[plan.scene.name]
        if plan.model == "lambert":
            rho = np.asarray(values["albedo"])
            cos = light[2]  # N = (0, 0, 1) at the centre
            ambient = AMBIENT if plan.scene.name == "tilted" else 0.0
            np.testing.assert_allclose(direct[centre], rho * (cos * INTENSITY + ambient), rtol=1e-12)
            np.testing.assert_allclose(direct, lambert_by_hand(rho, light, ambient, 15), rtol=1e-12, atol=1e-15)
        elif plan.scene.name == "head_on":
            # N = L = V = H: GGX's πD = 1/α², both G1 = 1 and N·V = 1, Schlick's F = F0
            kd, f0, alpha = np.asarray(values["kd"]), np.asarray(values["f0"]), values["roughness"]
            np.testing.assert_allclose(direct[centre], INTENSITY * (kd + f0 / (4 * alpha**2)), rtol=1e-12)
        checked.add((plan.model, plan.scene.name))
    assert len(checked) == 4
    assert {e["model"] for e in read_index(out)["samples"]} == {"lambert", "cook-torrance"}


def lambert_by_hand(rho: np.ndarray, light: list[float], ambient: float, size: int) -> np.ndarray:
    """ρ (I max(N·L, 0) + ambient) on the sphere, the background elsewhere (orthographic,
    pixel centres spanning [−1, 1]², y up)."""
    x = (np.arange(size) + 0.5) / size * 2 - 1
    xx, yy = np.meshgrid(x, -x)
    r2 = xx**2 + yy**2
    inside = r2 < 1
    nz = np.sqrt(np.where(inside, 1 - r2, 0.0))
    to_light = np.asarray(light) / np.linalg.norm(light)
    cos = np.maximum(xx * to_light[0] + yy * to_light[1] + nz * to_light[2], 0.0)
    radiance = rho * (INTENSITY * cos[..., None] + ambient)
    return np.where(inside[..., None], radiance, BACKGROUND)


# --- checks -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "model,parameters,message",
    [
        ("cook-torrance", {"roughness": 1.5}, "parameters: roughness = 1.5 is outside its range [0, 1]"),
        ("cook-torrance", {"f0": [0.1, 1.2, 0.3]}, "parameters: f0 = [0.1, 1.2, 0.3] is outside its range [0, 1]"),
        ("cook-torrance", {"roughness": {"low": 0.5, "high": 2.0, "steps": 3}}, "roughness = 2.0 is outside its range"),
        (
            "lambert",
            {"albedo": [0.5, -0.1, 0.5]},
            "parameters: albedo = [0.5, -0.1, 0.5] is outside its range [0, inf]",
        ),
        ("blinn-phong", {"exponent": -1.0}, "parameters: exponent = -1.0 is outside its range [0, inf]"),
        ("lambert", {"albedo": 0.5}, "albedo must be a list of 3 numbers, got 0.5"),
        ("cook-torrance", {"ks": 0.5}, "unknown cook-torrance parameter(s) ks; expected kd, f0, roughness"),
        ("ward", {}, "unknown model 'ward'; expected one of strauss, phong, lambert, blinn-phong, cook-torrance"),
    ],
)
def test_registry_ranges_and_names_are_one_line_errors(tmp_path, model, parameters, message):
    write_scenes(tmp_path)
    with pytest.raises(SpecError) as caught:
        parse_spec({"group": [group("g", model, parameters)]}, base_dir=tmp_path)
    assert message in str(caught.value) and "\n" not in str(caught.value)


def test_a_group_without_a_model_is_told_so(tmp_path):
    write_scenes(tmp_path)
    table = group("g", "strauss", {})
    del table["model"]
    with pytest.raises(SpecError, match="\\[\\[group\\]\\] 'g': missing key 'model'; one of strauss, phong"):
        parse_spec({"group": [table]}, base_dir=tmp_path)


def test_a_sidecar_out_of_the_registry_range_is_refused(tmp_path):
    write_scenes(tmp_path)
    spec = parse_spec({"group": [group("la", "lambert", {"albedo": [0.5, 0.5, 0.5]})]}, base_dir=tmp_path)
    generate(spec, tmp_path / "out")
    sidecar = tmp_path / "out" / "la-0000.json"
    data = json.loads(sidecar.read_text())
    data["parameters"]["albedo"] = [0.5, -1.0, 0.5]
    sidecar.write_text(json.dumps(data))
    with pytest.raises(StraussFitError, match=r"lambert albedo = \[0.5, -1.0, 0.5\] is outside its range"):
        load_sample(sidecar)
    with pytest.raises(SpecError, match="unknown model 'ward'; expected one of strauss, phong, lambert"):
        render_model("ward", None, None)


# --- Strauss and Phong unchanged ----------------------------------------------------------

CLASSIC_SCENE = """[camera]
projection = "orthographic"
width = 12
height = 12

[[light]]
kind = "directional"
direction = [0.4, 0.5, 1.0]
intensity = 1.0
color = [1.0, 0.9, 0.8]

[[light]]
kind = "point"
position = [-2.0, 1.0, 3.0]
intensity = 4.0

[[light]]
kind = "ambient"
intensity = 0.1

[background]
kind = "checkerboard"
point = [0.0, 0.0, -3.0]
normal = [0.0, 0.0, 1.0]
square_size = 0.5
colors = [[0.8, 0.8, 0.75], [0.15, 0.2, 0.35]]
color = [0.0, 0.0, 0.0]

[render]
depth = 2
"""
CLASSIC_SPEC = {
    "seed": 7,
    "group": [
        {
            "name": "s-grid",
            "model": "strauss",
            "scenes": ["scene.toml"],
            "formats": ["exr", "png"],
            "parameters": {
                "color": [0.8, 0.3, 0.2],
                "smoothness": [0.0, 0.7, 1.0],
                "metalness": [0.0, 1.0],
                "transparency": [0.0, 0.6],
                "ior": 1.4,
            },
        },
        {
            "name": "s-rand",
            "model": "strauss",
            "scenes": ["scene.toml"],
            "sampling": "random",
            "count": 2,
            "formats": ["exr"],
            "parameters": {
                "color": {"low": 0.1, "high": 0.9},
                "smoothness": {"low": 0.0, "high": 1.0},
                "metalness": {"low": 0.0, "high": 1.0},
            },
            "sensor": {"exposure": 1.5, "gain": 500.0, "read_noise": 0.01},
        },
        {
            "name": "p-grid",
            "model": "phong",
            "scenes": ["scene.toml"],
            "formats": ["exr", "png"],
            "parameters": {
                "ka": {"values": [0.5, [0.1, 0.2, 0.3]]},
                "kd": 0.6,
                "ks": [0.4, 0.5, 0.6],
                "exponent": [2.0, 200.0],
                "diffuse_color": [0.2, 0.4, 0.8],
                "blinn": [False, True],
            },
        },
        {
            "name": "p-rand",
            "model": "phong",
            "scenes": ["scene.toml"],
            "sampling": "random",
            "count": 3,
            "formats": ["exr"],
            "parameters": {
                "exponent": {"low": 2.0, "high": 2000.0, "scale": "log"},
                "kd": {"low": 0.1, "high": 1.0},
                "specular_color": {"low": 0.5, "high": 1.0},
                "blinn": [False, True],
            },
            "sensor": {"gain": 1000.0},
        },
    ],
}
#: Recorded with the hand-written Strauss and Phong tables, before synth's models came from
#: the registry: per sample, the SHA-256 (first 16 hex digits) of its files' names and
#: digests ("name digest" lines, sorted).
CLASSIC_PLAN = "681dacecc2fc92a7bad1b0a50b2719730864c4a7997c3582b9b0410462de2961"
CLASSIC_DIGESTS = {
    "index": "9f506fbb5ec7b3ca",
    "p-grid-0000": "61a9750bd5984024",
    "p-grid-0001": "9215d10b24a650b0",
    "p-grid-0002": "53177c43910c686f",
    "p-grid-0003": "5bbfdc6d5dda0da5",
    "p-grid-0004": "b9ca1ba4352afe7a",
    "p-grid-0005": "5feaf6d3bcccda37",
    "p-grid-0006": "2226175a8acdc20c",
    "p-grid-0007": "f929ff058aa20453",
    "p-rand-0000": "73909d303484aeb0",
    "p-rand-0001": "09b2b613b21dafae",
    "p-rand-0002": "35efe22fb57fdb2e",
    "s-grid-0000": "8dbf552150635c6e",
    "s-grid-0001": "2ae03ed3197e7421",
    "s-grid-0002": "3ad86857c7578434",
    "s-grid-0003": "a9c0eee4d2e48d6f",
    "s-grid-0004": "d124c571db859bef",
    "s-grid-0005": "1fa651efc08f8351",
    "s-grid-0006": "e07b44ea861c7cf2",
    "s-grid-0007": "599fa7bd61cbe7a8",
    "s-grid-0008": "40b6c2bce5a12447",
    "s-grid-0009": "5c34cb48a4dc5efc",
    "s-grid-0010": "528cd22cf6922357",
    "s-grid-0011": "462a224dc60867ac",
    "s-rand-0000": "f990d7d8bd1961b6",
    "s-rand-0001": "7bdbe9d0e7c053e1",
    "s-rand-0002": "eba9857d74bd39ea",
    "s-rand-0003": "8730fde1cde32436",
    "s-rand-0004": "3eb7e223c55c4796",
    "s-rand-0005": "5eb4db9cb17d1efc",
}
#: Per sample, the noise-free float64 radiance's fingerprint: the pixels of the sphere's
#: mask, and the image's sum, sum of squares and maximum (compared to 1e-9). Not a digest of
#: its bytes: their last bits depend on the processor (XLA's code for one with AVX-512 gave
#: other bits than the machines these digests were first recorded on: 2026-12-04), while
#: the files, rounded to their formats, stay identical.
CLASSIC_CLEAN = {
    "s-grid-0000": (112, 385.6408470008173, 666.893493435063, 3.7844118284407937),
    "s-grid-0001": (112, 209.70888801977082, 165.6878045123686, 1.7167684008667883),
    "s-grid-0002": (112, 385.1886658700291, 666.293244881527, 3.7841818496410804),
    "s-grid-0003": (112, 209.25670688898265, 165.39276413231357, 1.7167328935964534),
    "s-grid-0004": (112, 324.2176708665575, 407.3948483781637, 3.396582684671652),
    "s-grid-0005": (112, 184.7955918084844, 117.4428299599932, 1.4032126468143484),
    "s-grid-0006": (112, 146.70806725245453, 82.45739409585002, 1.5601769411423299),
    "s-grid-0007": (112, 113.57233288992913, 51.93202658618571, 0.7999999999496116),
    "s-grid-0008": (112, 140.3, 87.49861949887081, 0.7999999999496116),
    "s-grid-0009": (112, 113.23264328941642, 52.32294852217454, 0.7999999999496116),
    "s-grid-0010": (112, 90.93140735914594, 47.52024365335787, 0.7999999999496116),
    "s-grid-0011": (112, 91.79833085944105, 42.327605813597714, 0.7999999999496116),
    "s-rand-0000": (112, 397.2198692407362, 692.1663528501253, 3.776499247573343),
    "s-rand-0001": (112, 501.76333146445853, 954.0772287860781, 4.011165726700864),
    "s-rand-0002": (112, 140.3, 87.49861949887081, 0.7999999999496116),
    "s-rand-0003": (112, 90.95337036463232, 47.42396923401872, 0.7999999999496116),
    "s-rand-0004": (112, 224.98266148874615, 156.53522007877643, 1.513215666468404),
    "s-rand-0005": (112, 315.8385466088922, 381.33530880510716, 2.285466170615663),
    "p-grid-0000": (112, 370.1262463483469, 650.6685405346764, 4.561646244421871),
    "p-grid-0001": (112, 595.3611835191964, 1409.6761079438775, 4.851060395806227),
    "p-grid-0002": (112, 259.6236109917526, 264.1987669805158, 2.1946895318746455),
    "p-grid-0003": (112, 263.9369328175216, 275.7650088087081, 2.4712173591513547),
    "p-grid-0004": (112, 366.0942463483469, 642.2061048125962, 4.545646244421871),
    "p-grid-0005": (112, 591.3291835191962, 1395.5952956536794, 4.835060395806227),
    "p-grid-0006": (112, 255.5916109917526, 258.4916579843058, 2.1786895318746455),
    "p-grid-0007": (112, 259.90493281752157, 269.9505199210969, 2.4552173591513546),
    "p-rand-0000": (112, 777.7861400609854, 2192.4214884460675, 4.49250718707083),
    "p-rand-0001": (112, 598.450262719849, 1250.10634102983, 3.3598477970851763),
    "p-rand-0002": (112, 736.1789147456334, 1974.379265797364, 4.6554579462986405),
}


def test_strauss_and_phong_datasets_are_unchanged(tmp_path):
    (tmp_path / "scene.toml").write_text(CLASSIC_SCENE)
    spec = parse_spec(CLASSIC_SPEC, source="spec.toml", base_dir=tmp_path)
    samples = plan_samples(spec)
    assert plan_digest(spec, samples) == CLASSIC_PLAN
    for sample in samples:
        image, mask = render_clean(sample)
        image, mask = np.asarray(image, dtype=np.float64), np.asarray(mask, dtype=bool)
        count, total, squares, peak = CLASSIC_CLEAN[sample.id]
        assert int(mask.sum()) == count, sample.id
        np.testing.assert_allclose(
            [image.sum(), (image**2).sum(), image.max()], [total, squares, peak], rtol=1e-9, err_msg=sample.id
        )
    out = tmp_path / "out"
    generate(spec, out)
    lines: dict[str, list[str]] = {}
    for path in sorted(out.iterdir()):
        lines.setdefault(path.name.split(".")[0], []).append(
            f"{path.name} {hashlib.sha256(path.read_bytes()).hexdigest()}"
        )
    digests = {key: hashlib.sha256("\n".join(found).encode()).hexdigest()[:16] for key, found in lines.items()}
    assert digests == CLASSIC_DIGESTS
    assert set(CLASSIC_CLEAN) == {sample.id for sample in samples}

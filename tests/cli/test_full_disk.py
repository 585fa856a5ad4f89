"""A full disk, for every command that writes: one line naming the file, exit status 2,
nothing written or half-written, nothing overwritten; a dataset or a chain continues with
--resume once there is space again, to exactly what an uninterrupted run makes.

Each test runs twice (:mod:`faults`): on a real, small tmpfs where the machine allows
mounting one, and with the writer patched to fail past a byte budget.
"""

import numpy as np
import pytest
from faults import disk_fixture  # noqa: F401 - the fixture "disk"

import strauss_fit as sf
import strauss_fit.inference.sampler._backends as sampler_backends
from data_synth import read_index
from strauss_fit.inference.sampler import load_chain
from strauss_fit.io.images import write_image
from strauss_fit_cli.main import main
from support import SCENES, SMALL_MATERIAL, files_of, key_and_fill_scene, key_and_fill_toml, noisy_target

TRUTH = dict(color=(0.7, 0.4, 0.2), smoothness=0.6, metalness=0.4)


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def assert_full_disk_error(code, err, name):
    assert code == 2, err
    assert err.startswith("strauss-fit: error: ") and err.count("\n") == 1 and "Traceback" not in err
    assert "No space left on device" in err and name in err, err


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A 48 x 48 noisy target (its EXR does not compress below the space left), its scene
    and a fit result, on an ordinary disk."""
    folder = tmp_path_factory.mktemp("fitted")
    (folder / "scene.toml").write_text(key_and_fill_toml(48, material=SMALL_MATERIAL))
    scene = key_and_fill_scene(48, material=SMALL_MATERIAL)
    write_image(folder / "target.exr", noisy_target(scene, sf.Material(**TRUTH), 0.01, seed=5).pixels)
    argv = ["fit", folder / "target.exr", "--scene", folder / "scene.toml", "--free", "color,smoothness,metalness"]
    assert main([str(a) for a in argv + ["-o", folder / "fit.json", "--quality", "fast", "--quiet"]]) in (0, 1)
    return folder


def test_render_writes_nothing_and_overwrites_nothing(disk, capsys):
    disk.fill(8 * 1024)
    precious = disk.folder / "x.exr"
    precious.write_bytes(b"precious")
    code, out, err = run(
        capsys,
        *("render", SCENES / "basic.toml", "-o", precious, "--mask", disk.folder / "m.png", "--force"),
        *("--width", "128", "--height", "128"),
    )
    assert_full_disk_error(code, err, "x.exr")
    assert "wrote" not in out
    assert disk.files() == ["x.exr"] and precious.read_bytes() == b"precious"  # no temporary, no mask


def test_fit_leaves_no_result_when_its_image_does_not_fit(disk, fitted, capsys):
    disk.fill(24 * 1024)  # the result (~10 KB) fits, the fitted EXR (~27 KB) does not
    code, out, err = run(
        capsys,
        *("fit", fitted / "target.exr", "--scene", fitted / "scene.toml", "--quality", "fast", "--quiet"),
        *("--free", "color,smoothness,metalness", "-o", disk.folder / "r.json", "--render-fit", disk.folder / "f.exr"),
    )
    assert_full_disk_error(code, err, "f.exr")
    assert disk.files() == []


def test_report_leaves_no_part_of_the_report(disk, fitted, capsys):
    disk.fill(48 * 1024)
    code, _, err = run(capsys, "report", "--fit", fitted / "fit.json", "-o", disk.folder / "report.html")
    assert_full_disk_error(code, err, str(disk.folder))
    assert disk.files() == []  # no REPORT_files/, no PNG, no .md, no temporary


def test_synth_stops_cleanly_and_resumes_to_the_same_dataset(disk, reference, capsys):
    spec, complete = reference
    out = disk.folder / "data"
    disk.fill(40 * 1024)
    code, _, err = run(capsys, "synth", spec, "-o", out, "--quiet")
    assert_full_disk_error(code, err, str(out))
    assert "samples are complete" in err and "--resume" in err
    listed = {name for entry in read_index(out)["samples"] for name in entry["files"].values()}
    assert set(disk.files()) == {"data"} | {f"data/{name}" for name in listed | {"index.json"}}  # nothing else
    disk.free_up()
    assert run(capsys, "synth", spec, "-o", out, "--resume", "--quiet")[0] == 0
    assert files_of(out) == files_of(complete)


def test_sample_keeps_the_chain_as_it_was_and_resumes_it(disk, fitted, capsys, monkeypatch, tmp_path):
    monkeypatch.setattr(sampler_backends, "FLUSH_SECONDS", 0.0)  # write the chain after (about) every step
    argv = ["sample", fitted / "target.exr", "--scene", fitted / "scene.toml", "--fit", fitted / "fit.json"]
    argv += ["--sigma", "0.01", "--walkers", "16", "--max-steps", "150", "--check-every", "25", "--quiet"]
    whole = tmp_path / "whole.h5"
    assert run(capsys, *argv, "-o", whole)[0] in (0, 1)
    chain = disk.folder / "c.h5"
    disk.fill(100 * 1024)  # the chain is written whole each time: old and new must fit
    code, _, err = run(capsys, *argv, "-o", chain)
    assert code == 2 and "No space left on device" in err and "keeps the" in err and "--resume" in err, err
    kept = load_chain(chain)  # readable: exactly what the last successful write left
    steps = len(kept.chain)
    assert 0 < steps < 150 and f"keeps the {steps} steps" in err
    assert disk.files() == ["c.h5"]
    disk.free_up()
    resumed = [a for a in argv if a != "--sigma" and a != "0.01"]
    resumed = resumed[: resumed.index("--fit")] + resumed[resumed.index("--fit") + 2 :]
    resumed = [a for a in resumed if a not in ("--walkers", "16")]
    assert run(capsys, *resumed, "-o", chain, "--resume")[0] in (0, 1)
    np.testing.assert_array_equal(load_chain(chain).chain, load_chain(whole).chain)

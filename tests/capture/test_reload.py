"""A capture's fit read back from its result (what ``sample`` and ``report`` start from)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from data_synth.capture import example_capture_spec, write_capture
from strauss_fit.capture import capture_inputs, open_capture
from strauss_fit.errors import CaptureError
from strauss_fit.fitting.capture import CaptureFitOptions, relative_rms
from strauss_fit.fitting.capture_result import fit_capture, is_capture_result, reload_capture_fit

SMALL = dict(frame=(120, 96), center_px=(60.3, 47.8), radius_px=30.0)


@pytest.mark.parametrize("exposure", ["global", "per-image"])
def test_reloaded_fit_reproduces_the_recorded_residual(tmp_path, exposure):
    write_capture(example_capture_spec("plastic", noise_sd=0.003, supersample=1, seed=5, **SMALL), tmp_path / "cap")
    result = fit_capture(
        open_capture([tmp_path / "cap"]),
        CaptureFitOptions(exposure=exposure),
        holdout="3",
        compare=(),
        inputs=capture_inputs(["cap"], None, None),
    )
    (tmp_path / "fit.json").write_text(json.dumps(result))
    data = json.loads((tmp_path / "fit.json").read_text())
    assert is_capture_result(data)
    # the recorded path is relative to the result's folder, not to the working directory
    samples, fit = reload_capture_fit(data, base=tmp_path)
    assert samples.count == result["images_fitted"] < result["images"]
    assert relative_rms(fit.predicted, samples.values, samples.usable) == pytest.approx(
        result["residual"]["relative_rms"], rel=1e-9
    )
    sd = np.sqrt(np.diag(fit.clustered))
    assert sd[3] == pytest.approx(result["uncertainty"]["smoothness"])


def test_reload_refuses_what_is_not_a_capture_result(tmp_path):
    with pytest.raises(CaptureError, match="not a capture"):
        reload_capture_fit({"free": ["color"]})
    with pytest.raises(CaptureError, match="records no capture"):
        reload_capture_fit({"images_fitted": 1, "circle": {}, "settings": {}})

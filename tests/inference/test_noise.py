"""Tests of the noise estimators (numpy only: synthetic spheres, no renderer needed).

Tolerances are set from the reported standard error: an estimate must lie within 4 SE of
the truth (a 4σ band, false failure rate ~1e-4 per channel), and the SE must be small
enough for the check to mean something."""

from __future__ import annotations

import math

import numpy as np
import pytest

from strauss_fit.color import srgb_decode, srgb_encode
from strauss_fit.stats import noise as ne
from strauss_fit.stats.noise import _describe, _level_line

# ------------------------------------------------------------------------------------------
# synthetic spheres
# ------------------------------------------------------------------------------------------


def sphere(
    n: int = 128,
    *,
    supersample: int = 1,
    exponent: float = 50.0,
    spec: float = 0.6,
    color=(0.8, 0.5, 0.3),
    background=(0.6, 0.6, 0.6),
    pattern: float = 0.0,
    pattern_freq: float = 25.0,
):
    """A lit sphere: Lambert + Blinn highlight, orthographic view, over a flat background.
    ``supersample`` > 1 renders at that factor and box-averages (partly covered edge
    pixels). ``pattern`` adds a high-contrast stripe texture (the same pattern in every
    channel, with colour (1, 0.8, -0.6)) that aliases near the rim.
    Returns image (n, n, 3), coverage (n, n) in [0, 1]."""
    m = n * supersample
    c = (np.arange(m) + 0.5) / m * 2 - 1
    x, y = np.meshgrid(c, -c)
    r2 = x * x + y * y
    inside = r2 < 1
    z = np.sqrt(np.maximum(1 - r2, 0))
    light = np.array([0.4, 0.5, 1.0])
    light /= np.linalg.norm(light)
    half = light + np.array([0, 0, 1.0])
    half /= np.linalg.norm(half)
    ndotl = np.maximum(x * light[0] + y * light[1] + z * light[2], 0)
    ndoth = np.maximum(x * half[0] + y * half[1] + z * half[2], 0)
    col = np.asarray(color, float)
    img = col * (0.1 + 0.9 * ndotl)[..., None] + (spec * ndoth**exponent)[..., None]
    if pattern:
        stripes = np.sign(np.sin(pattern_freq * x / (z + 0.15)))
        img = img + pattern * stripes[..., None] * np.array([1.0, 0.8, -0.6]) * 0.5
    img = np.where(inside[..., None], img, np.asarray(background, float))
    f = supersample
    img = img.reshape(n, f, n, f, 3).mean(axis=(1, 3))
    cover = inside.reshape(n, f, n, f).mean(axis=(1, 3))
    return img, cover


SIGMA = np.array([0.01, 0.005, 0.02])  # green half of red, blue larger


def within(est: ne.NoiseEstimate, truth: np.ndarray, k: float = 4.0) -> np.ndarray:
    return np.abs(est.sigma - truth) <= k * est.stderr


# ------------------------------------------------------------------------------------------
# additive noise
# ------------------------------------------------------------------------------------------


def test_recovers_known_sigma_per_channel():
    img, cover = sphere(128)
    rng = np.random.default_rng(1)
    est = ne.estimate_noise(img + rng.normal(size=img.shape) * SIGMA, cover >= 1)
    assert np.all(est.relative_stderr < 0.03)  # ~10 000 positions: SE ≈ 1.5 %
    assert np.all(within(est, SIGMA)), (est.sigma / SIGMA, est.relative_stderr)
    assert np.all(est.resolved)
    assert est.n_pixels > 0.8 * est.n_candidates


def test_standard_error_matches_spread_over_draws():
    img, cover = sphere(64)
    mask = cover >= 1
    ests, ses = [], []
    for seed in range(30):
        rng = np.random.default_rng(100 + seed)
        e = ne.estimate_noise(img + rng.normal(size=img.shape) * SIGMA, mask, check=False)
        ests.append(e.sigma / SIGMA)
        ses.append(e.stderr / SIGMA)
    ests, ses = np.array(ests), np.array(ses)
    # pooled over channels: 90 draws; sd of a sd estimate from 90 draws is ~7.5 %
    ratio = ests.std(axis=0, ddof=1).mean() / ses.mean()
    assert 0.7 < ratio < 1.35, ratio
    assert abs(ests.mean() - 1) < 3 * ses.mean() / math.sqrt(ests.size), ests.mean()  # unbiased


def test_channels_are_estimated_independently():
    img, cover = sphere(128)
    rng = np.random.default_rng(2)
    sigma = np.array([0.02, 0.0005, 0.008])  # 40× between R and G
    est = ne.estimate_noise(img + rng.normal(size=img.shape) * sigma, cover >= 1)
    assert np.all(within(est, sigma)), est.sigma / sigma
    # a pooled estimate (today's behaviour) would give G about 0.0125: 25× too large
    assert est.sigma[1] < 2 * sigma[1]


def test_robust_to_a_sharp_highlight():
    img, cover = sphere(96, exponent=3000.0, spec=3.0)  # a tiny, very bright highlight
    rng = np.random.default_rng(3)
    sigma = SIGMA / 10  # 1e-3: the highlight is 1000× the noise
    noisy = img + rng.normal(size=img.shape) * sigma
    est = ne.estimate_noise(noisy, cover >= 1)
    assert np.all(within(est, sigma)), est.sigma / sigma
    # without the robust clipping (Immerkær's mean |r|) the highlight inflates it far
    # beyond the SE
    naive = ne.estimate_noise(noisy, cover >= 1, robust="mean_abs", check=False)
    assert np.all(naive.sigma - sigma > 6 * est.stderr), naive.sigma / sigma


@pytest.mark.parametrize("mask_rule", ["full", "any"])
def test_robust_to_an_antialiased_silhouette(mask_rule):
    # bright background: the partly covered pixels are steps of ~0.3–0.5
    img, cover = sphere(96, supersample=4)
    mask = cover >= 1 if mask_rule == "full" else cover > 0
    rng = np.random.default_rng(4)
    sigma = SIGMA / 5
    noisy = img + rng.normal(size=img.shape) * sigma
    est = ne.estimate_noise(noisy, mask)
    assert np.all(within(est, sigma)), est.sigma / sigma
    if mask_rule == "any":  # the same mask without margin or clipping is inflated by the edge
        naive = ne.estimate_noise(noisy, mask, robust="mean_abs", margin=0, check=False)
        assert np.all(naive.sigma - sigma > 6 * est.stderr), naive.sigma / sigma


def test_noise_free_render_is_flagged_and_far_below_noise():
    img, cover = sphere(64)
    est = ne.estimate_noise(img, cover >= 1)
    assert np.all(est.sigma < 1e-4)  # the content floor of smooth shading
    assert not np.any(est.resolved)  # and it says that it cannot tell


def test_robust_to_a_sharp_pattern_on_the_sphere():
    # hard-edged stripes (steps of 0.4) resolved by the pixels: the clipping removes them
    img, cover = sphere(64, pattern=0.4, pattern_freq=40.0)
    rng = np.random.default_rng(5)
    est = ne.estimate_noise(img + rng.normal(size=img.shape) * SIGMA, cover >= 1)
    assert np.all(within(est, SIGMA)), est.sigma / SIGMA
    assert np.all(est.resolved)


def test_aliased_pattern_is_flagged():
    # the same stripes far finer than a pixel: they alias into noise-like content, which the
    # estimator cannot separate from noise, but the content is the same in every channel,
    # so the channels' residuals correlate and the estimate is marked unresolved
    img, cover = sphere(64, pattern=0.4, pattern_freq=150.0)
    rng = np.random.default_rng(5)
    est = ne.estimate_noise(img + rng.normal(size=img.shape) * SIGMA, cover >= 1)
    assert np.all(est.sigma > SIGMA)  # an upper bound
    assert not np.any(est.resolved)
    assert not any(est.details["channels_independent"])


def test_background_only_mask_and_grey_image():
    rng = np.random.default_rng(6)
    grey = np.full((80, 80), 0.3) + rng.normal(size=(80, 80)) * 0.01
    est = ne.estimate_noise(grey)
    assert est.sigma.shape == (1,)
    assert abs(est.sigma[0] - 0.01) < 4 * est.stderr[0]


# ------------------------------------------------------------------------------------------
# bad input
# ------------------------------------------------------------------------------------------


def test_no_usable_pixels():
    img, cover = sphere(32)
    with pytest.raises(ne.NoiseEstimationError, match="neighbourhood inside the usable mask"):
        ne.estimate_noise(img, np.zeros(cover.shape, bool))


def test_tiny_image():
    with pytest.raises(ne.NoiseEstimationError, match="need at least"):
        ne.estimate_noise(np.random.default_rng(0).normal(size=(6, 6, 3)))


def test_constant_image():
    with pytest.raises(ne.NoiseEstimationError, match="identically zero"):
        ne.estimate_noise(np.full((32, 32, 3), 0.5))


def test_linear_ramp_has_no_measurable_noise():
    x = np.linspace(0, 1, 40)
    ramp = np.broadcast_to((x[None, :] + 0.5 * x[:, None])[..., None], (40, 40, 3))
    with pytest.raises(ne.NoiseEstimationError, match="identically zero"):
        ne.estimate_noise(ramp)


def test_nan_in_usable_pixels():
    img, cover = sphere(48)
    img = img.copy()
    img[24, 24, 1] = np.nan
    with pytest.raises(ne.NoiseEstimationError, match="NaN"):
        ne.estimate_noise(img, cover >= 1)


def test_nan_outside_the_mask_is_ignored():
    img, cover = sphere(64)
    rng = np.random.default_rng(7)
    noisy = img + rng.normal(size=img.shape) * SIGMA
    noisy[0, 0, :] = np.nan
    est = ne.estimate_noise(noisy, cover >= 1)
    assert np.all(np.isfinite(est.sigma))


def test_mask_shape_mismatch_and_bad_arguments():
    img, _ = sphere(32)
    with pytest.raises(ne.NoiseEstimationError, match="shape"):
        ne.estimate_noise(img, np.ones((31, 32), bool))
    with pytest.raises(ne.NoiseEstimationError, match="kernel"):
        ne.estimate_noise(img, kernel="sobel")
    with pytest.raises(ne.NoiseEstimationError, match="shape"):
        ne.estimate_noise(np.zeros((4, 4, 4, 4)))


# ------------------------------------------------------------------------------------------
# signal-dependent noise
# ------------------------------------------------------------------------------------------


def sensor(img, gain, read, rng):
    shot = rng.poisson(np.maximum(img, 0) * gain) / gain if gain else img
    return shot + rng.normal(size=img.shape) * read


def test_poisson_gaussian_recovery():
    img, cover = sphere(128)
    rng = np.random.default_rng(8)
    gain, read = 1000.0, 0.005
    pg = ne.estimate_noise_model(sensor(img, gain, read, rng), cover >= 1)
    assert np.all(np.abs(pg.a - 1 / gain) < 4 * pg.a_stderr), pg.a * gain
    assert np.all(np.abs(pg.b - read**2) < 4 * pg.b_stderr), np.sqrt(pg.b) / read
    assert np.all(pg.signal_dependent)
    assert np.all(pg.a_stderr * gain < 0.15)  # a is pinned to better than 15 %
    sm = pg.sigma_map(img)
    truth = np.sqrt(img / gain + read**2)
    m = cover >= 1
    assert abs(np.sqrt(np.mean(sm[m] ** 2) / np.mean(truth[m] ** 2)) - 1) < 0.05


def test_read_noise_only_is_not_signal_dependent():
    img, cover = sphere(128)
    rng = np.random.default_rng(9)
    pg = ne.estimate_noise_model(sensor(img, 0.0, 0.01, rng), cover >= 1)
    assert not np.any(pg.signal_dependent)
    assert np.all(np.abs(np.sqrt(pg.b) / 0.01 - 1) < 0.1)


def test_noise_model_bad_input():
    with pytest.raises(ne.NoiseEstimationError):
        ne.estimate_noise_model(np.full((64, 64, 3), 0.2))
    with pytest.raises(ne.NoiseEstimationError, match="at least 200"):
        ne.estimate_noise_model(np.random.default_rng(0).normal(size=(12, 12, 3)))


def test_noise_from_sensor():
    values = np.array([[-0.1, 0.0, 0.25, 1.0]])
    s = ne.noise_from_sensor(values, gain=400.0, read_noise=0.01)
    np.testing.assert_allclose(s, np.sqrt(np.maximum(values, 0) / 400 + 1e-4))
    s2 = ne.noise_from_sensor(values, gain=400.0, read_noise=0.01, exposure=2.0, values_are="radiance")
    np.testing.assert_allclose(s2, np.sqrt(2 * np.maximum(values, 0) / 400 + 1e-4))
    np.testing.assert_allclose(ne.noise_from_sensor(values, 0.0, 0.02), 0.02)
    with pytest.raises(ne.NoiseEstimationError):
        ne.noise_from_sensor(values, gain=-1.0, read_noise=0.01)


def test_sensor_map_matches_the_measured_scatter():
    # the plug-in σ map (from the noisy target) predicts the scatter of repeated draws
    rng = np.random.default_rng(10)
    level = np.linspace(0.05, 0.9, 400)
    draws = np.stack([sensor(level, 800.0, 0.004, rng) for _ in range(400)])
    predicted = ne.noise_from_sensor(draws, 800.0, 0.004)
    ratio = draws.std(axis=0) / np.sqrt(np.mean(predicted**2, axis=0))
    assert abs(np.median(ratio) - 1) < 0.02


# ------------------------------------------------------------------------------------------
# 8-bit quantisation
# ------------------------------------------------------------------------------------------


def test_srgb_round_trip_and_constants():
    v = np.linspace(0, 1, 256)
    np.testing.assert_allclose(srgb_encode(srgb_decode(v)), v, atol=1e-12)
    assert srgb_decode(np.array(0.04045)) == pytest.approx(0.04045 / 12.92)


def test_quantisation_sigma():
    # dark: the linear segment, code width (1/255)/12.92
    assert ne.quantisation_sigma(np.array(0.001)) == pytest.approx(1 / 255 / 12.92 / math.sqrt(12), rel=1e-6)
    # mid-level: the derivative of the decoding curve
    x = 0.2
    v = srgb_encode(np.array(x))
    dv = 2.4 / 1.055 * ((v + 0.055) / 1.055) ** 1.4
    assert ne.quantisation_sigma(np.array(x)) == pytest.approx(dv / 255 / math.sqrt(12), rel=0.02)
    q = ne.quantisation_sigma(np.linspace(0.01, 0.99, 50))  # (codes 0 and 255 are half bins)
    assert np.all(np.diff(q) >= -1e-12)  # grows with the level
    assert q.max() < 3e-3 and q.min() > 5e-5


def quantise(img):
    codes = np.round(srgb_encode(img) * 255)
    return srgb_decode(codes / 255), np.any(codes == 255, axis=-1)


def test_noise_free_8bit_floor_is_the_quantisation():
    img, cover = sphere(96)
    q, clipped = quantise(img)
    usable = (cover >= 1) & ~clipped
    sq = ne.quantisation_sigma(q)
    est = ne.estimate_noise(q, usable, censor=(0.0, 1.0))
    rms_q = np.sqrt(np.mean(sq[usable] ** 2, axis=0))
    # the estimator sees at most about the quantisation noise (often less: the error of a
    # smooth signal is a staircase, not white) ...
    assert np.all(est.sigma < 1.5 * rms_q)
    # ... and the combined map never goes below the per-pixel quantisation floor
    smap = ne.combine_with_quantisation(est.sigma, q, usable)
    assert np.all(smap[usable] >= sq[usable] - 1e-15)
    assert np.all(np.sqrt(np.mean(smap[usable] ** 2, axis=0)) < 1.5 * rms_q)


def test_noisy_8bit_includes_quantisation_once():
    img, cover = sphere(128)
    rng = np.random.default_rng(11)
    q, clipped = quantise(img + rng.normal(size=img.shape) * SIGMA)
    usable = (cover >= 1) & ~clipped
    est = ne.estimate_noise(q, usable, censor=(0.0, 1.0))
    total = np.sqrt(SIGMA**2 + np.mean(ne.quantisation_sigma(img)[usable] ** 2, axis=0))
    assert np.all(np.abs(est.sigma - total) < 4 * est.stderr + 0.02 * total), est.sigma / total
    smap = ne.combine_with_quantisation(est.sigma, q, usable)
    truth = np.sqrt(SIGMA**2 + ne.quantisation_sigma(q) ** 2)
    ratio = np.sqrt(np.mean(smap[usable] ** 2, axis=0) / np.mean(truth[usable] ** 2, axis=0))
    assert np.all(np.abs(ratio - 1) < 0.08), ratio
    given = ne.combine_with_quantisation(SIGMA, q, sigma_from_image=False)
    np.testing.assert_allclose(given, np.sqrt(SIGMA**2 + ne.quantisation_sigma(q) ** 2))


# ------------------------------------------------------------------------------------------
# the verdict
# ------------------------------------------------------------------------------------------


def test_verdict_right_and_wrong_model():
    img, cover = sphere(96, exponent=200.0)
    wrong, _ = sphere(96, exponent=150.0)
    mask = cover >= 1
    rng = np.random.default_rng(12)
    target = img + rng.normal(size=img.shape) * SIGMA
    est = ne.estimate_noise(target, mask)
    right = ne.mismatch_verdict(img - target, est.sigma, mask, 6, sigma_rel_se=est.relative_stderr)
    bad = ne.mismatch_verdict(wrong - target, est.sigma, mask, 6, sigma_rel_se=est.relative_stderr)
    assert right.consistent and abs(right.chi2_dof - 1) < 4 * right.expected_sd
    assert not bad.consistent
    # the spread includes the noise estimate's own uncertainty (≈ 2 × relative SE, the
    # channels' errors independent, each channel a third of χ²)
    eps = est.relative_stderr
    assert right.expected_sd >= 2 * float(np.sqrt(np.sum(eps**2))) / 3
    assert right.expected_sd > math.sqrt(2 / right.dof)


def test_per_channel_sigma_makes_every_channel_consistent():
    # today's pooled σ: a green-quiet, blue-noisy target gets the same ± on every channel
    img, cover = sphere(96)
    mask = cover >= 1
    rng = np.random.default_rng(13)
    target = img + rng.normal(size=img.shape) * SIGMA
    est = ne.estimate_noise(target, mask)
    v = ne.mismatch_verdict(img - target, est.sigma, mask, 6, sigma_rel_se=est.relative_stderr)
    assert all(abs(p["z"]) < 4 for p in v.per_channel)
    pooled = float(np.sqrt(np.mean(est.sigma**2)))
    vp = ne.mismatch_verdict(img - target, pooled, mask, 6)
    chis = [p["chi2_dof"] for p in vp.per_channel]
    assert chis[1] < 0.3 and chis[2] > 1.5  # green looks too good, blue looks inconsistent


def test_bin_variances_are_each_bins_own_statistics():
    """The level bins' statistics, computed for all bins at once, equal each bin's own:
    the median |r| (odd and even counts) on the first pass, the mean square after, the mean
    level and quantisation; bins under 30 positions are left out."""
    rng = np.random.default_rng(4)
    counts = [31, 40, 7, 55]  # the third is too small to keep
    idx = np.repeat(np.arange(4), counts)
    rng.shuffle(idx)
    mu = rng.uniform(0.0, 1.0, idx.size)
    r = rng.normal(0.0, 0.1, idx.size)
    qv = rng.uniform(0.0, 1e-4, idx.size)
    for first in (True, False):
        level, variance, count, quantisation = _level_line._bin_variances(mu, r, qv, idx, 4, first=first, factor=1.7)
        kept = [b for b in range(4) if counts[b] >= 30]
        assert count.tolist() == [counts[b] for b in kept]
        for row, b in enumerate(kept):
            sel = idx == b
            spread = (np.median(np.abs(r[sel])) / ne.MAD_CONSTANT) ** 2 if first else np.mean(r[sel] ** 2) * 1.7
            assert level[row] == pytest.approx(np.mean(mu[sel]), rel=1e-13)
            assert quantisation[row] == pytest.approx(np.mean(qv[sel]), rel=1e-13)
            assert variance[row] == pytest.approx(spread - np.mean(qv[sel]), rel=1e-12)
    # a bin of discrete residuals, more than half exactly 0: its MAD is 0, the mean square stands in
    r0 = np.where(np.arange(idx.size) % 3 == 0, 0.02, 0.0)
    _, variance, _, quantisation = _level_line._bin_variances(mu, r0, np.zeros_like(qv), idx, 4, first=True, factor=1.0)
    for row, b in enumerate(kept):
        assert variance[row] == pytest.approx(np.mean(r0[idx == b] ** 2), rel=1e-12)


def test_the_noise_model_stops_at_its_fixed_point_with_what_all_passes_give(monkeypatch):
    """Each pass of the noise model is a function of the previous a and b: once a pass
    repeats the one before, the remaining passes give the same model, so stopping there
    (as it does: fewer passes) changes nothing — on an additive image, where it stops
    after two passes, and on a signal-dependent one, where it runs them all."""
    passes = []
    robust_scale = _level_line._robust_scale
    monkeypatch.setattr(_level_line, "_robust_scale", lambda *a, **k: passes.append(1) or robust_scale(*a, **k))
    img, cover = sphere(64)
    additive = img + np.random.default_rng(2).normal(0.0, 0.01, img.shape)
    shot = sensor(*sphere(96)[:1], 2000.0, 0.003, np.random.default_rng(11))
    for noisy, usable, stops_early in ((additive, cover >= 1, True), (shot, sphere(96)[1] >= 1, False)):
        passes.clear()
        early = ne.estimate_noise_model(noisy, usable)
        early_passes = len(passes)
        with monkeypatch.context() as patch:
            patch.setattr(_level_line, "FIXED_POINT", -1.0)  # never stops early
            passes.clear()
            every = ne.estimate_noise_model(noisy, usable)
        assert (early_passes < len(passes) == 4) if stops_early else (early_passes == len(passes) == 4)
        np.testing.assert_allclose(np.concatenate([early.a, early.b]), np.concatenate([every.a, every.b]), rtol=1e-11)
        np.testing.assert_allclose(early.a_stderr, every.a_stderr, rtol=1e-11)
        assert early.n_pixels == every.n_pixels


def test_describe_noise_estimates_an_image_once(monkeypatch):
    # fitting a target again (another loss, a retry, a benchmark) reuses its noise estimate;
    # a changed pixel or another set of used pixels is another image
    image, cover = sphere(64)
    noisy = image + np.random.default_rng(3).normal(size=image.shape) * SIGMA
    usable = cover == 1
    calls = []
    real = ne.estimate_noise
    monkeypatch.setattr(_describe, "estimate_noise", lambda *a, **k: calls.append(1) or real(*a, **k))
    first = ne.describe_noise(noisy, usable, sidecar={})
    again = ne.describe_noise(noisy.copy(), usable.copy(), sidecar={})
    assert len(calls) == 1
    np.testing.assert_array_equal(first.b, again.b)
    assert first.source == again.source == "image" and first.notes == again.notes
    again.b[:] = 0.0  # the caller's copy: the memory keeps its own
    again.notes.append("changed by the caller")
    third = ne.describe_noise(noisy, usable, sidecar={})
    np.testing.assert_array_equal(third.b, first.b)
    assert third.notes == first.notes and len(calls) == 1
    changed = noisy.copy()
    changed[32, 32, 0] += 1e-9
    ne.describe_noise(changed, usable, sidecar={})
    fewer = usable.copy()
    fewer[usable.nonzero()[0][0], usable.nonzero()[1][0]] = False
    ne.describe_noise(noisy, fewer, sidecar={})
    assert len(calls) == 3
    # a given level or a sidecar's sensor is not an estimate
    assert ne.describe_noise(noisy, usable, given=0.01).source == "given" and len(calls) == 3


def test_the_level_line_fit_survives_a_bin_without_noise_and_matches_weighted_least_squares():
    """:func:`_fit_line` (the signal-dependent noise model's σ² = a·level + b): one bin of a
    noise-free 8-bit target has only quantisation variance (se ~ 1e-16, a weight 10¹⁴× the
    others), which made the inverse of the normal matrix report negative variances (a math
    domain error that ended a fit). The values are the ones recorded from that fit. On
    ordinary data the fit is weighted least squares (numpy.polyfit with weights 1/se)."""
    from strauss_fit.stats.noise._level_line import _fit_line

    x = np.array(
        [0.0780969866747178, 0.11058016741189494, 0.13574167886219324, 0.1546373470235953, 0.16920198140812687]
        + [0.1808213156669776, 0.19064733120721805, 0.19922385355293074, 0.2091433316622451]
    )
    y = np.array(
        [-2.2651990137719166e-08, -1.2604709560788536e-07, -1.6750087098334942e-07, -1.7671826673006894e-07]
        + [-2.4028206275825097e-07, -9.018482445870568e-07, -2.4670825080813833e-07, -2.521805609606961e-07]
        + [-2.642510643462172e-07]
    )
    se = np.array(
        [6.188894621286967e-08, 7.468741127300374e-08, 9.322629147479187e-08, 1.1226475835375102e-07]
        + [1.1628397664281499e-07, 1.3490974597999678e-16, 1.391802693178466e-07, 1.4896622949134697e-07]
        + [1.5559589991847797e-07]
    )
    a, b, sa, sb, red = _fit_line(x, y, se)
    assert np.isfinite([a, b, sa, sb, red]).all() and min(a, b) >= 0 and sa > 0 and sb > 0

    rng = np.random.default_rng(3)
    x = np.linspace(0.05, 0.9, 12)
    se = rng.uniform(0.5e-5, 2e-5, x.size)
    y = 3e-4 * x + 2e-5 + rng.normal(0, 1, x.size) * se
    a, b, sa, sb, _ = _fit_line(x, y, se)
    (a_ref, b_ref), cov = np.polyfit(x, y, 1, w=1 / se, cov="unscaled")
    np.testing.assert_allclose([a, b], [a_ref, b_ref], rtol=1e-9)
    red = np.sum(((y - a * x - b) / se) ** 2) / (x.size - 2)
    np.testing.assert_allclose([sa, sb], np.sqrt(np.diag(cov)) * np.sqrt(max(red, 1.0)), rtol=1e-9)

    a, b, sa, sb, _ = _fit_line(np.full(5, 0.3), np.full(5, 1e-5), np.full(5, 1e-6))  # one level: no slope
    assert a == 0.0 and b == pytest.approx(1e-5) and sa == np.inf

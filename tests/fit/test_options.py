"""Fit options and the quality presets: one table in the library, read by fits, sampling
and conversions alike, and FitOptions() is the balanced preset the command line uses."""

import pytest

import strauss_fit as sf
from strauss_fit.convert.converter import Settings
from strauss_fit.fitting.options import DEFAULT_QUALITY, QUALITY_PRESETS, FitOptions


def test_default_options_are_the_balanced_preset():
    assert DEFAULT_QUALITY == "balanced"
    assert FitOptions() == FitOptions.preset("balanced") == FitOptions.preset()
    balanced = QUALITY_PRESETS["balanced"]
    assert (FitOptions().starts, FitOptions().max_steps, FitOptions().rtol, FitOptions().atol) == (
        balanced["starts"],
        balanced["max_steps"],
        balanced["rtol"],
        balanced["atol"],
    )


@pytest.mark.parametrize("name", sorted(QUALITY_PRESETS))
def test_presets_set_the_fit_settings_and_explicit_values_override_them(name):
    preset = QUALITY_PRESETS[name]
    options = FitOptions.preset(name)
    assert (options.starts, options.max_steps, options.rtol, options.atol) == (
        preset["starts"],
        preset["max_steps"],
        preset["rtol"],
        preset["atol"],
    )
    changed = FitOptions.preset(name, starts=7, free=("color",), max_steps=None)
    assert changed.starts == 7 and changed.free == ("color",) and changed.max_steps == preset["max_steps"]


@pytest.mark.parametrize("name", sorted(QUALITY_PRESETS))
def test_sampling_and_conversion_read_the_same_table(name):
    preset = QUALITY_PRESETS[name]
    settings = sf.SampleSettings.preset(name)
    assert (settings.max_steps, settings.min_tau_multiple, settings.walkers) == (
        preset["sample_max_steps"],
        preset["min_tau_multiple"],
        preset["walkers"],
    )
    conversion = Settings.preset(name, starts=None)
    assert (conversion.starts, conversion.max_steps, conversion.rtol, conversion.atol) == (
        preset["starts"],
        preset["max_steps"],
        preset["rtol"],
        preset["atol"],
    )
    assert sf.SampleSettings() == sf.SampleSettings.preset("balanced", check_every=100, seed=0)


def test_an_unknown_preset_is_a_one_line_error():
    with pytest.raises(sf.StraussFitError, match="unknown quality preset 'slow'"):
        FitOptions.preset("slow")


@pytest.mark.parametrize(
    "fields,message",
    [
        (dict(noise=1e300), r"the noise level \(--noise\) must be from 1e-100 to 1e\+100 .*got 1e\+300"),
        (dict(noise=1e-300), r"the noise level \(--noise\) must be from 1e-100 to 1e\+100 .*got 1e-300"),
        (dict(noise=(0.01, 1e200, 0.01)), r"the noise level \(--noise\) must be from .*got 0.01, 1e\+200, 0.01"),
        (dict(noise=(0.01, 0.02)), r"the noise level \(--noise\) must be one positive number or three"),
        (dict(noise=-0.01), r"the noise level \(--noise\) must be one positive number or three"),
        (dict(reference_noise=1e300), r"the reference noise \(--reference-noise\) must be from 1e-100 to 1e\+100"),
        (dict(reference_noise=1e-300), r"the reference noise \(--reference-noise\) must be from 1e-100 to 1e\+100"),
    ],
)
def test_a_noise_level_whose_square_leaves_float64_is_refused_in_one_line(fields, message):
    with pytest.raises(sf.StraussFitError, match=message) as raised:
        FitOptions(**fields).validate()
    assert "\n" not in str(raised.value)


def test_noise_levels_at_the_ends_of_the_range_are_accepted():
    for value in (1e-100, 1e100, (1e-100, 0.01, 1e100)):
        FitOptions(noise=value).validate()
    FitOptions(reference_noise=1e-100).validate()
    FitOptions(reference_noise=1e100).validate()


@pytest.mark.parametrize(
    "fields,message",
    [
        (dict(max_steps=0), r"the solver step limit \(max_steps\) must be a whole number ≥ 1, got 0"),
        (dict(max_steps=-3), r"step limit \(max_steps\) must be a whole number ≥ 1, got -3"),
        (dict(max_steps=2.5), r"step limit \(max_steps\) must be a whole number ≥ 1, got 2.5"),
        (dict(max_steps=True), r"step limit \(max_steps\) must be a whole number ≥ 1, got True"),
        (dict(rtol=-1e-6), r"the solver tolerance rtol must be a finite number ≥ 0, got -1e-06"),
        (dict(atol=float("nan")), r"the solver tolerance atol must be a finite number ≥ 0, got nan"),
        (dict(rtol="1e-6"), r"the solver tolerance rtol must be a finite number ≥ 0, got '1e-6'"),
    ],
)
def test_the_solver_settings_are_checked_in_one_line(fields, message):
    """The library refuses what the command line's parsers refuse: a step limit below 1 (the
    Gauss–Newton loop then reported one evaluation) and a negative or non-finite tolerance."""
    with pytest.raises(sf.StraussFitError, match=message) as raised:
        FitOptions(**fields).validate()
    assert "\n" not in str(raised.value)


def test_the_solver_settings_at_their_ends_are_accepted():
    import numpy as np

    FitOptions(max_steps=1, rtol=0.0, atol=0.0).validate()
    FitOptions(max_steps=np.int64(5), rtol=np.float64(1e-9)).validate()

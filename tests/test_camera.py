import json

import pytest

from spikesim.camera import NOISE_TERMS, SpikeCamera


def test_defaults_are_the_published_magnitudes():
    cam = SpikeCamera()
    assert (cam.width, cam.height) == (400, 250)
    assert cam.readout_period_s == 25e-6
    # 0.47 % of the threshold per step at 20 kHz is half that per step at 40 kHz (a current).
    assert cam.dark_per_step == pytest.approx(0.0047 / 2, rel=0.01)
    assert cam.dark_current_hz * 50e-6 == pytest.approx(0.0047, rel=0.01)
    assert cam.gain_spread == 0.058 and cam.comparator_noise == 0.006 and cam.reset_loss == 0.002


def test_noiseless_switches_every_term_off():
    cam = SpikeCamera.noiseless()
    assert cam.is_noiseless and not cam.has_temporal_noise
    for term, off in NOISE_TERMS.items():
        assert getattr(cam, term) == off
    assert not SpikeCamera().is_noiseless


def test_without_names_unknown_terms():
    cam = SpikeCamera().without("comparator_noise", "shot_noise")
    assert cam.comparator_noise == 0 and cam.shot_noise == "off" and cam.gain_spread > 0
    with pytest.raises(ValueError, match="unknown noise term"):
        SpikeCamera().without("sunspots")


@pytest.mark.parametrize("field,value,message", [
    ("threshold_electrons", 0, "threshold_electrons"),
    ("threshold_electrons", float("nan"), "threshold_electrons"),
    ("readout_period_s", -1e-6, "readout_period_s"),
    ("readout_period_s", 5.0, "readout_period_s"),
    ("height", 0, "height"),
    ("width", 2.5, "width"),
    ("gain_spread", -0.1, "gain_spread"),
    ("gain_spread", 0.9, "gain_spread"),
    ("reset_loss", 1.0, "reset_loss"),
    ("dark_current_hz", 1e6, "dark_current_hz"),
    ("shot_noise", "loud", "shot_noise"),
    ("precision", "float16", "precision"),
])
def test_bad_parameters_are_named(field, value, message):
    with pytest.raises(ValueError, match=message):
        SpikeCamera(**{field: value})


def test_file_round_trip_and_errors(tmp_path):
    cam = SpikeCamera(height=20, width=30, comparator_noise=0.01)
    path = tmp_path / "cam.json"
    cam.save(path)
    assert SpikeCamera.from_file(path) == cam
    (tmp_path / "preset.json").write_text(json.dumps({"preset": "noiseless", "width": 64}))
    loaded = SpikeCamera.from_file(tmp_path / "preset.json")
    assert loaded.is_noiseless and loaded.width == 64
    (tmp_path / "bad.json").write_text(json.dumps({"widht": 64}))
    with pytest.raises(ValueError, match=r"bad.json.*widht"):
        SpikeCamera.from_file(tmp_path / "bad.json")
    (tmp_path / "broken.json").write_text("{")
    with pytest.raises(ValueError, match="broken.json"):
        SpikeCamera.from_file(tmp_path / "broken.json")
    (tmp_path / "cam.toml").write_text('preset = "noiseless"\nheight = 8\n')
    assert SpikeCamera.from_file(tmp_path / "cam.toml").height == 8


def test_the_scsim_preset_is_scsims_constants_and_fires_at_its_dark_rate():
    """SCSim's camera as a preset (docs/sensor.md "Other simulators' cameras"): a 20 kHz readout
    and its dark current, 93.5 thresholds per second, so 93.5 x 50 us spikes per step in the dark."""
    import numpy as np

    from spikesim.camera import SCSIM_TERMS
    from spikesim.patterns import constant_frames
    from spikesim.simulate import Simulator
    cam = SpikeCamera.preset("scsim").replace(height=48, width=48)
    assert all(getattr(cam, k) == v for k, v in SCSIM_TERMS.items())
    steps = 20000
    stream = Simulator(cam, backend="numpy", seed=3).run(constant_frames(0.0, steps, 48, 48))
    rate = stream.counts().mean() / steps
    # the pixels' normal dark currents (spread 0.39, clipped at 0) over 2,304 pixels: about 1 % standard error
    assert rate == pytest.approx(93.5 * 50e-6, rel=0.05)
    assert SpikeCamera.from_dict({"preset": "scsim", "height": 8, "width": 8}).readout_period_s == 50e-6


def test_the_normal_dark_current_law_is_scsims_clipped_at_zero():
    import numpy as np
    from scipy.stats import norm

    from spikesim.fixed_pattern import draw_pixel_parameters
    cam = SpikeCamera.realistic(height=200, width=200, dark_current_law="normal")
    dark = draw_pixel_parameters(cam, seed=4).dark_per_step
    zero = float((dark == 0).mean())
    want = norm.cdf(-1 / 0.39)  # the share of a normal draw below 0
    assert zero == pytest.approx(want, abs=4 * np.sqrt(want / dark.size))
    assert dark.std() / cam.dark_per_step == pytest.approx(0.39, rel=0.03)
    assert dark.mean() / cam.dark_per_step == pytest.approx(1.0, rel=0.01)
    lognormal = draw_pixel_parameters(SpikeCamera.realistic(height=200, width=200), seed=4).dark_per_step
    assert (lognormal > 0).all()


def test_the_dark_current_law_is_recorded_only_when_switched():
    assert "dark_current_law" not in SpikeCamera().to_dict()  # every earlier camera keeps its identity
    cam = SpikeCamera(dark_current_law="normal")
    assert cam.to_dict()["dark_current_law"] == "normal" and SpikeCamera.from_dict(cam.to_dict()) == cam
    with pytest.raises(ValueError, match="dark_current_law"):
        SpikeCamera(dark_current_law="gamma")


def test_resetting_by_the_fired_level_keeps_the_charge_the_comparator_noise_left():
    """SCSim's reset rule: a pixel fires when its comparator noise is low, so subtracting the level
    it fired at takes less than the threshold on average and the dark rate rises (by +0.5 % at
    SCSim's constants); without comparator noise the two rules are one."""
    import numpy as np

    from spikesim.patterns import constant_frames
    from spikesim.simulate import Simulator
    base = SpikeCamera.noiseless(height=40, width=40, comparator_noise=0.05)
    y = 0.05
    rates = {rule: Simulator(base.replace(reset_rule=rule), backend="numpy", seed=2)
             .run(constant_frames(y, 20_000, 40, 40)).counts().mean() / 20_000 for rule in ("threshold", "fired")}
    assert rates["fired"] > rates["threshold"] * 1.005  # 5 % comparator noise: a clear rise
    quiet = SpikeCamera.noiseless(height=8, width=8)
    a = Simulator(quiet, backend="numpy", seed=1).run(constant_frames(0.3, 500, 8, 8))
    b = Simulator(quiet.replace(reset_rule="fired"), backend="numpy", seed=1).run(constant_frames(0.3, 500, 8, 8))
    assert a == b
    assert np.isfinite(rates["fired"])


def test_a_simulator_of_a_camera_name_says_how_to_make_the_camera():
    from spikesim.simulate import Simulator
    with pytest.raises(TypeError, match=r"SpikeCamera.preset\('realistic'\)"):
        Simulator("realistic")

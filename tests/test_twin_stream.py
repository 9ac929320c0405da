"""The noise-free twin (generate --twin, spikesim.simulate.TwinSimulator): a second stream of the
same frames from the camera with every noise term off but its initial state, for self-supervised
denoisers and noise studies (the pair SCSim writes)."""
import dataclasses

import numpy as np
import pytest

from spikesim.camera import NOISE_TERMS, SpikeCamera
from spikesim.dataset import TWIN_SPIKES, open_dataset, verify
from spikesim.generation import PRESETS, generate, plan_rllr
from spikesim.simulate import Simulator, TwinSimulator, twin_camera


def _frames(n=300, h=8, w=16, seed=0):
    rng = np.random.default_rng(seed)
    base = rng.uniform(0.02, 0.6, (h, w)).astype(np.float32)
    return [base * np.float32(1 + 0.3 * np.sin(i / 40)) for i in range(n)]


def test_the_twin_camera_has_every_noise_term_off_but_the_initial_state():
    cam = SpikeCamera.realistic(height=8, width=16)
    twin = twin_camera(cam)
    for term, off in NOISE_TERMS.items():
        if term != "random_initial_state":
            assert getattr(twin, term) == off, term
    assert twin.random_initial_state == cam.random_initial_state
    assert not twin.has_temporal_noise


@pytest.mark.parametrize("keyframe_every", [1, 4])
def test_a_twin_stream_is_the_twin_camera_run_alone_on_the_same_frames(keyframe_every):
    cam = SpikeCamera.realistic(height=8, width=16)
    frames = _frames()[::keyframe_every]
    twins: list = []
    pair = TwinSimulator(Simulator(cam, backend="numpy", seed=3, chunk_steps=64), twins.append)
    ours = np.concatenate([p.unpack() for p in pair.stream(iter(frames), keyframe_every=keyframe_every)])
    theirs = np.concatenate([p.unpack() for p in twins])
    alone = Simulator(cam, backend="numpy", seed=3).run(frames, keyframe_every=keyframe_every).unpack()
    twin_alone = Simulator(twin_camera(cam), backend="numpy", seed=3).run(frames, keyframe_every=keyframe_every).unpack()
    np.testing.assert_array_equal(ours, alone)  # the camera's stream is untouched by its twin
    np.testing.assert_array_equal(theirs, twin_alone)
    # same light, same phase: the rates agree within the noise, and the twin is not the stream
    assert theirs.mean() == pytest.approx(ours.mean(), rel=0.1)
    assert (theirs != ours).any()


def test_the_twin_starts_in_the_cameras_phase():
    cam = SpikeCamera.realistic(height=8, width=16, threshold_mismatch=0.0, threshold_offset=0.0)
    a = Simulator(cam, backend="numpy", seed=5).params.initial_accumulator
    b = Simulator(twin_camera(cam), backend="numpy", seed=5).params.initial_accumulator
    np.testing.assert_array_equal(a, b)  # ideal thresholds on both sides: the same charge


def test_generate_twin_writes_a_verified_twin_for_every_scene(tmp_path):
    preset = PRESETS["small"].replace(height=12, width=32, rllr_steps=82, rllr_gt_stride=41)
    jobs = plan_rllr(preset, seed=1, count=2, source="pattern")
    plain_digest = jobs[0].digest
    jobs = [dataclasses.replace(j, twin=True) for j in jobs]
    assert jobs[0].digest != plain_digest  # a twin is part of what was made
    generate(jobs, tmp_path, workers=1, show_progress=False)
    assert verify(tmp_path) == []
    for s in open_dataset(tmp_path):
        twin = s.twin_spikes()
        assert twin.shape == s.spikes().shape
        assert s.meta["twin"]["file"] == TWIN_SPIKES
        assert s.meta["twin"]["camera"]["dark_current_hz"] == 0.0 and s.meta["camera"]["dark_current_hz"] > 0
        assert twin.mean() == pytest.approx(s.spikes().mean(), rel=0.15, abs=0.01)
    dat = tmp_path / "rllr_0001" / TWIN_SPIKES
    data = bytearray(dat.read_bytes())
    data[5] ^= 0xFF
    dat.write_bytes(bytes(data))
    assert any(f"rllr_0001/{TWIN_SPIKES}" in p and "checksum" in p for p in verify(tmp_path))


def test_a_scene_without_a_twin_says_so(tmp_path):
    preset = PRESETS["small"].replace(height=12, width=32, rllr_steps=82, rllr_gt_stride=41)
    generate(plan_rllr(preset, seed=1, count=1, source="pattern"), tmp_path, workers=1, show_progress=False)
    (s,) = open_dataset(tmp_path)
    assert not s.has_twin and "twin" not in s.meta["job"]
    with pytest.raises(ValueError, match="--twin"):
        s.twin_spikes()


def test_simulate_twin_writes_both_streams_with_sidecars_naming_their_cameras(tmp_path, capsys):
    import json

    from pipelines.cli import main
    from spikesim.stream import read_dat
    out = tmp_path / "s.dat"
    assert main(["simulate", "--height", "8", "--width", "16", "--backend", "numpy", "--steps", "120", "--quiet",
                 "--twin", "-o", str(out)]) == 0
    twin = tmp_path / "s_twin.dat"
    a, b = read_dat(out, 8, 16).unpack(), read_dat(twin, 8, 16).unpack()
    assert a.shape == b.shape == (120, 8, 16)
    side_a = json.loads((tmp_path / "s.dat.json").read_text())
    side_b = json.loads((tmp_path / "s_twin.dat.json").read_text())
    assert side_a["twin"] == "s_twin.dat" and side_b["twin_of"] == "s.dat"
    assert side_b["camera"]["dark_current_hz"] == 0 and side_a["camera"]["dark_current_hz"] > 0
    # a twin path that is not a stream simulate wrote is refused before anything is simulated
    (tmp_path / "t_twin.dat").write_text("keep me")
    assert main(["simulate", "--height", "8", "--width", "16", "--steps", "10", "--quiet", "--twin",
                 "-o", str(tmp_path / "t.dat")]) == 2
    assert (tmp_path / "t_twin.dat").read_text() == "keep me" and not (tmp_path / "t.dat").exists()

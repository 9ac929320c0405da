"""model.reconstruct: the documented Python call that runs a method on a spike stream."""
from __future__ import annotations

import numpy as np
import pytest
import torch

import model
from model.threads import describe_threads


def _spikes(steps=123, h=16, w=24, seed=0):
    return np.random.default_rng(seed).random((steps, h, w)) < 0.1


def test_tfp_frames_are_window_means():
    s = _spikes()
    frames = model.reconstruct(s, method="tfp", threads=1)
    assert frames.shape == (3, 16, 24) and frames.dtype == np.float32
    np.testing.assert_allclose(frames[1], s[41:82].mean(0), rtol=1e-6)


def test_the_shipped_network_and_the_thread_choice(tmp_path):
    s = torch.from_numpy(_spikes(steps=5 * 41 + 7))
    frames = model.reconstruct(s, threads=1)
    assert frames.shape == (5, 16, 24) and np.isfinite(frames).all()
    assert "1 thread(s), as asked" in describe_threads()
    model.reconstruct(s, method="tfp")  # threads=0: chosen from the free cores, as the commands do
    assert "cores, load average" in describe_threads()


def test_a_dat_path_and_bad_input(tmp_path):
    from spikesim.stream import SpikeStream, write_dat

    s = _spikes()
    write_dat(tmp_path / "s.dat", SpikeStream.from_bool(s))
    frames = model.reconstruct(tmp_path / "s.dat", method="tfp", height=16, width=24, threads=1)
    np.testing.assert_allclose(frames[0], s[:41].mean(0), rtol=1e-6)
    with pytest.raises(ValueError, match="no whole 41-step window"):
        model.reconstruct(s[:40], method="tfp")
    with pytest.raises(ValueError, match="expected \\(steps, H, W\\)"):
        model.reconstruct(s[0], method="tfp")


def test_span_tfp_is_the_mean_over_the_windows_in_reach_in_linear_time():
    """tfp:N restacked every window in reach for each frame (quadratic, and all of them in memory);
    the running sum gives the same frames, reading each window at most twice."""
    from model.methods import SpanTFPMethod
    from model.streaming import TensorWindows

    s = torch.from_numpy(np.random.default_rng(3).random((9, 41, 5, 6)) < 0.2)

    class Counting(TensorWindows):
        reads = 0

        def windows(self, a, b):
            Counting.reads += b - a
            return super().windows(a, b)

    for n_windows, kept in ((1, 64), (3, 64), (5, 64), (21, 64), (5, 1), (21, 1)):  # counts kept, or read again
        Counting.reads = 0
        method = SpanTFPMethod(f"TFP-{41 * n_windows}", 41 * n_windows, chunk=2)
        method.KEPT_WINDOWS = kept
        frames = dict(method.frames(Counting(s)))
        half = n_windows // 2
        for i in range(9):
            lo, hi = max(0, i - half), min(8, i + half)
            expect = s[lo:hi + 1].float().sum(dim=(0, 1)) / ((hi - lo + 1) * 41)
            torch.testing.assert_close(frames[i], expect)
        assert Counting.reads <= (9 if 2 * (n_windows // 2) + 1 <= kept else 2 * 9)


@pytest.mark.parametrize("bad, says", [
    (np.full((41, 12, 12), np.nan), "nan"), (np.full((41, 12, 12), 0.3), "0.3"), (np.full((41, 12, 12), 255), "255"),
    (-np.ones((41, 12, 12)), "-1"), (np.zeros((41, 12, 12), complex), "complex"), (np.zeros((41, 0, 12)), "side"),
    (np.array([["a"]]), "dtype")])
def test_only_a_spike_array_is_reconstructed(bad, says):
    """NaN, 0.3, 255, -1 and complex inputs gave plausible frames (the code tested s != 0)."""
    from model.inference import reconstruct
    with pytest.raises(ValueError, match=says):
        reconstruct(bad, method="tfp")


def test_bool_and_01_arrays_agree_and_a_bad_window_is_named():
    from model.inference import reconstruct
    rng = np.random.default_rng(0)
    spikes = rng.random((82, 12, 12)) < 0.2
    np.testing.assert_array_equal(reconstruct(spikes, method="tfp"), reconstruct(spikes.astype(np.float32), method="tfp"))
    for window in (0, 40, -1):
        with pytest.raises(ValueError, match="window"):
            reconstruct(spikes, method="tfp", window=window)


def test_a_video_of_odd_sides_is_written_with_even_ones(tmp_path):
    pytest.importorskip("imageio_ffmpeg")
    import imageio.v3 as iio

    from pipelines.reconstruct import _Video, even_sides
    assert even_sides(np.zeros((125, 201), np.uint8)).shape == (126, 202)
    v = _Video(tmp_path, 10, gif=False, mp4=True)
    for _ in range(3):
        v.add(np.zeros((125, 201), np.uint8))
    v.close()
    assert (tmp_path / "frames.mp4").stat().st_size > 0
    assert iio.imread(tmp_path / "frames.mp4", index=0).shape[:2] == (126, 202)


def test_a_dat_path_takes_what_the_command_takes(tmp_path):
    """model.reconstruct(path) advised header_columns and drop_partial and took neither, nor flip."""
    from model.inference import reconstruct
    from spikesim.stream import SpikeStream, write_dat
    rng = np.random.default_rng(1)
    spikes = rng.random((82, 12, 16)) < 0.3
    path = tmp_path / "s.dat"
    write_dat(path, SpikeStream.from_bool(spikes), flip=False)
    top_down = reconstruct(path, method="tfp", height=12, width=16, flip=False, header_columns=0)
    np.testing.assert_allclose(top_down, reconstruct(spikes, method="tfp"))
    bottom_up = reconstruct(path, method="tfp", height=12, width=16, flip=True, header_columns=0)
    np.testing.assert_allclose(bottom_up, top_down[:, ::-1])
    path.write_bytes(path.read_bytes() + b"\0" * 5)  # a file cut off mid-frame
    with pytest.raises(ValueError, match="drop_partial"):
        reconstruct(path, method="tfp", height=12, width=16, header_columns=0)
    assert reconstruct(path, method="tfp", height=12, width=16, header_columns=0, drop_partial=True).shape == (2, 12, 16)


@pytest.mark.parametrize("device, says", [("gpu", "is not a device"), ("mps", "no MPS device")])
def test_a_device_this_machine_lacks_is_named_for_every_method(device, says):
    """"mps" used to blame the weights ("not a checkpoint of this project") and "gpu" raised torch's
    own error; TFP took any device and ran on the CPU."""
    from spikesim.errors import UnavailableError
    if device == "mps" and torch.backends.mps.is_available():
        pytest.skip("this machine has an MPS device")
    s = np.random.default_rng(0).random((82, 12, 12)) < 0.2
    for method in ("tfp", "lrrep"):
        with pytest.raises((ValueError, UnavailableError), match=says):
            model.reconstruct(s, method=method, device=device)


def test_a_flipped_view_is_reconstructed_as_its_copy():
    """np.flip and [:, ::-1] give views with negative strides, which torch refused with its own
    message (issue 40, round 5)."""
    s = np.random.default_rng(1).random((41, 8, 10)) < 0.3
    flipped = np.flip(s, 1)
    assert any(st < 0 for st in flipped.strides)
    np.testing.assert_array_equal(model.reconstruct(flipped, method="tfp"),
                                  model.reconstruct(flipped.copy(), method="tfp"))


@pytest.mark.parametrize("kwargs, says", [
    ({"flip": "false"}, "flip: expected True, False or None"),  # was taken as True: the image upside down
    ({"height": 0}, "height: expected a positive"),             # was taken as "not given"
    ({"height": "16"}, "height: expected a positive"),
    ({"chunk": "x"}, "chunk: expected an integer"),
    ({"threads": "a"}, "threads: expected an integer"),
    ({"method": None}, "method: expected a method spec"),
    ({"height": 9}, "height=9, but the array's frames are 8 x 10"),   # was ignored for an array
    ({"header_columns": 16}, "applies to a .dat path"),
    ({"flip": True}, "applies to a .dat path"),
])
def test_keyword_arguments_of_the_wrong_kind_are_named(kwargs, says, tmp_path):
    s = np.random.default_rng(2).random((41, 8, 10)) < 0.3
    with pytest.raises(ValueError, match=says):
        model.reconstruct(s, **({"method": "tfp"} | kwargs))


@pytest.mark.parametrize("device", ["gpu", 0, "cpu:1", torch.device("meta")])
def test_load_pretrained_names_a_device_it_does_not_know(device):
    """"gpu" raised torch's own error, 0 and "cpu:1" blamed the shipped weights (rounds five, seven);
    the message named the command's --device to a Python caller (round seven, low)."""
    with pytest.raises(ValueError, match=r"^device=.* is not a device") as info:
        model.load_pretrained("lrrep", device=device)
    assert "--device" not in str(info.value)


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA device")
def test_a_missing_gpu_is_named_as_the_argument_in_python_and_the_flag_on_the_command_line():
    from model.training import resolve_device
    from spikesim.errors import UnavailableError
    with pytest.raises(UnavailableError, match=r"^device='cuda' asked for.*use device='cpu' or 'auto'"):
        model.load_pretrained("lrrep", device="cuda")
    with pytest.raises(UnavailableError, match=r"^--device cuda asked for.*use --device cpu or auto"):
        resolve_device("cuda")

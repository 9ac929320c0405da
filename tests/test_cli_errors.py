"""Bad input to simulate, render, demo, tradeoff and golden, as a hostile user would give it: each
case must end in one error line that names the flag or file, exit status 2, and no traceback.

Every case runs in-process through `pipelines.cli.main`, which returns the status (argparse's
own errors included) rather than exiting.
"""
from __future__ import annotations

import os
import shlex
from pathlib import Path

import numpy as np
import pytest

from cli_testing import one_line, run_cli

H, W = 8, 16
SIM = f"--height {H} --width {W} --backend numpy --quiet"


@pytest.fixture(scope="module")
def bad(tmp_path_factory) -> Path:
    """A folder of good and broken inputs."""
    from spikesim.imageio import write_exr

    d = tmp_path_factory.mktemp("bad")
    good = np.full((4, H, W), 0.2, np.float32)
    np.save(d / "good.npy", good)
    np.save(d / "2d.npy", good[0])
    np.save(d / "wrong_shape.npy", np.full((4, H + 1, W), 0.2, np.float32))
    np.save(d / "zero_frames.npy", good[:0])
    np.save(d / "text.npy", np.full((4, H, W), "a"))
    np.save(d / "object.npy", np.full((4, H, W), None, dtype=object), allow_pickle=True)
    for name, value in (("nan", np.nan), ("inf", np.inf), ("negative", -1.0)):
        a = good.copy()
        a[2, 3, 4] = value
        np.save(d / f"{name}.npy", a)
    (d / "trunc.npy").write_bytes((d / "good.npy").read_bytes()[:200])
    (d / "garbage.npy").write_bytes(b"hello, not an array")
    (d / "empty_file.npy").write_bytes(b"")
    with open(d / "archive.npy", "wb") as f:
        np.savez(f, frames=good)
    (d / "bad_header.npy").write_bytes(b"\x93NUMPY\x01\x00" + b"{'descr': nonsense}" * 4)
    (d / "frames.txt").write_text("0.2\n")
    (d / "no_exr").mkdir()
    (d / "bad_exr").mkdir()
    (d / "bad_exr" / "000.exr").write_bytes(b"not an EXR")
    (d / "nan_exr").mkdir()
    write_exr(d / "nan_exr" / "000.exr", good[0])
    write_exr(d / "nan_exr" / "001.exr", np.full((H, W), np.nan, np.float32))
    (d / "shape_exr").mkdir()
    write_exr(d / "shape_exr" / "000.exr", np.zeros((H, W + 1), np.float32))
    (d / "cam_bad.json").write_text("{not json")
    (d / "cam_list.json").write_text("[1, 2]")
    (d / "cam_unknown.json").write_text('{"foo": 1}')
    (d / "cam_negative.json").write_text('{"height": -5}')
    (d / "cam_bad.toml").write_text("height = = 3")
    (d / "cam.yaml").write_text("height: 8\n")
    (d / "cam.dat.json").write_text('{"height": 8, "width": 16}')
    (d / "side.dat.json").mkdir()
    (d / "unreadable.npy").write_bytes((d / "good.npy").read_bytes())
    (d / "unreadable.npy").chmod(0)
    os.mkfifo(d / "fifo.json")  # opening it would wait for a writer forever
    return d


# (id, command line with {d} for the folder above, what the error line must name)
CASES = [
    # simulate: the irradiance source
    ("sim-frames-missing", f"simulate --frames {{d}}/missing.npy {SIM}", "missing.npy"),
    ("sim-frames-empty-file", f"simulate --frames {{d}}/empty_file.npy {SIM}", "empty_file.npy"),
    ("sim-frames-garbage", f"simulate --frames {{d}}/garbage.npy {SIM}", "garbage.npy"),
    ("sim-frames-npz", f"simulate --frames {{d}}/archive.npy {SIM}", "archive.npy"),
    ("sim-frames-bad-header", f"simulate --frames {{d}}/bad_header.npy {SIM}", "bad_header.npy"),
    ("sim-frames-truncated", f"simulate --frames {{d}}/trunc.npy {SIM}", "trunc.npy"),
    ("sim-frames-object", f"simulate --frames {{d}}/object.npy {SIM}", "object.npy"),
    ("sim-frames-text", f"simulate --frames {{d}}/text.npy {SIM}", "text.npy"),
    ("sim-frames-zero", f"simulate --frames {{d}}/zero_frames.npy {SIM}", "zero_frames.npy"),
    ("sim-frames-2d", f"simulate --frames {{d}}/2d.npy {SIM}", "2d.npy"),
    ("sim-frames-shape", f"simulate --frames {{d}}/wrong_shape.npy {SIM}", "wrong_shape.npy"),
    ("sim-frames-nan", f"simulate --frames {{d}}/nan.npy {SIM}", "nan.npy"),
    ("sim-frames-inf", f"simulate --frames {{d}}/inf.npy {SIM}", "inf.npy"),
    ("sim-frames-negative", f"simulate --frames {{d}}/negative.npy {SIM}", "negative.npy"),
    ("sim-frames-unreadable", f"simulate --frames {{d}}/unreadable.npy {SIM}", "unreadable.npy"),
    ("sim-frames-txt", f"simulate --frames {{d}}/frames.txt {SIM}", "--frames"),
    ("sim-frames-no-exr", f"simulate --frames {{d}}/no_exr {SIM}", "no_exr"),
    ("sim-frames-bad-exr", f"simulate --frames {{d}}/bad_exr {SIM}", "000.exr"),
    ("sim-frames-nan-exr", f"simulate --frames {{d}}/nan_exr {SIM}", "001.exr"),
    ("sim-frames-shape-exr", f"simulate --frames {{d}}/shape_exr {SIM}", "000.exr"),
    ("sim-frames-too-few", f"simulate --frames {{d}}/good.npy --steps 100 {SIM}", "--steps"),
    ("sim-frames-and-scene", f"simulate --frames {{d}}/good.npy --scene ball {SIM}", "--scene"),
    ("sim-motion-without-scene", f"simulate --frames {{d}}/good.npy --motion {{d}}/cam_bad.json {SIM}", "--motion"),
    # simulate: numbers
    ("sim-steps-0", f"simulate --steps 0 {SIM}", "--steps"),
    ("sim-steps-negative", f"simulate --steps -5 {SIM}", "--steps"),
    ("sim-steps-text", f"simulate --steps ten {SIM}", "--steps"),
    ("sim-keyframe-every-0", f"simulate --keyframe-every 0 {SIM}", "--keyframe-every"),
    ("sim-height-0", "simulate --height 0 --steps 5", "--height"),
    ("sim-width-negative", "simulate --width -3 --steps 5", "--width"),
    ("sim-seed-negative", f"simulate --seed -1 --steps 5 {SIM}", "--seed"),
    ("sim-peak-y-negative", f"simulate --peak-y -1 --steps 5 {SIM}", "--peak-y"),
    ("sim-peak-y-nan", f"simulate --peak-y nan --steps 5 {SIM}", "--peak-y"),
    ("sim-peak-y-huge", f"simulate --peak-y 1e39 --steps 5 {SIM}", "--peak-y"),
    ("sim-spp-0", f"simulate --scene ball --spp 0 --steps 2 {SIM}", "--spp"),
    # simulate: camera files
    ("sim-camera-missing", f"simulate --camera {{d}}/missing.json --steps 5 {SIM}", "--camera"),
    ("sim-camera-directory", f"simulate --camera {{d}} --steps 5 {SIM}", "--camera"),
    ("sim-camera-bad-json", f"simulate --camera {{d}}/cam_bad.json --steps 5 {SIM}", "cam_bad.json"),
    ("sim-camera-list", f"simulate --camera {{d}}/cam_list.json --steps 5 {SIM}", "cam_list.json"),
    ("sim-camera-unknown-key", f"simulate --camera {{d}}/cam_unknown.json --steps 5 {SIM}", "cam_unknown.json"),
    ("sim-camera-negative", f"simulate --camera {{d}}/cam_negative.json --steps 5 {SIM}", "cam_negative.json"),
    ("sim-camera-bad-toml", f"simulate --camera {{d}}/cam_bad.toml --steps 5 {SIM}", "cam_bad.toml"),
    ("sim-camera-fifo", f"simulate --camera {{d}}/fifo.json --steps 5 {SIM}", "--camera"),
    ("sim-camera-device", f"simulate --camera /dev/null --steps 5 {SIM}", "--camera"),
    ("sim-camera-yaml", f"simulate --camera {{d}}/cam.yaml --steps 5 {SIM}", "--camera"),
    # simulate: the output
    ("sim-out-directory", f"simulate --steps 5 {SIM} -o {{d}}", "--out"),
    ("sim-out-under-file", f"simulate --steps 5 {SIM} -o {{d}}/good.npy/x.dat", "--out"),
    ("sim-out-sidecar-directory", f"simulate --steps 5 {SIM} -o {{d}}/side.dat", "side.dat.json"),
    ("sim-out-sidecar-is-input", f"simulate --steps 5 --camera {{d}}/cam.dat.json {SIM} -o {{d}}/cam.dat", "--camera"),
    ("sim-out-is-input", f"simulate --frames {{d}}/good.npy {SIM} -o {{d}}/good.npy", "--out"),
    # simulate: scenes
    ("sim-scene-unknown", f"simulate --scene nosuchscene --steps 2 {SIM}", "nosuchscene"),
    ("sim-scene-xml-missing", f"simulate --scene {{d}}/missing.xml --steps 2 {SIM}", "missing.xml"),
    ("sim-scene-light-unknown", f"simulate --scene ball --light dusk --steps 2 {SIM}", "dusk"),
    ("sim-scene-motion-missing", f"simulate --scene ball --motion {{d}}/missing.json --steps 2 {SIM}", "--motion"),
    ("sim-scene-lights-bad", f"simulate --scene ball --lights {{d}}/cam_bad.json --steps 2 {SIM}", "cam_bad.json"),
    # render
    ("render-scene-unknown", "render nosuchscene --out {d}/r", "nosuchscene"),
    ("render-scene-xml-missing", "render {d}/missing.xml --out {d}/r", "missing.xml"),
    ("render-scene-directory", "render {d} --out {d}/r", "scene.xml"),
    ("render-light-unknown", "render ball --light dusk --height 10 --width 16 --out {d}/r", "dusk"),
    ("render-steps-negative", "render ball --steps -1 --out {d}/r", "--steps"),
    ("render-steps-empty-range", "render ball --steps 5:2 --out {d}/r", "--steps"),
    ("render-steps-text", "render ball --steps x --out {d}/r", "--steps"),
    ("render-steps-zero-stride", "render ball --steps 0:10:0 --out {d}/r", "--steps"),
    ("render-steps-huge-range", "render ball --steps 0:100000000000 --out {d}/r", "--steps"),
    ("render-steps-repeated", "render ball --steps 0,0,0 --out {d}/r", "more than once"),  # round eight
    ("bench-streams-huge", "bench --streams 100000000", "at most 1,024 streams"),  # round nine
    ("bench-repeats-huge", "bench --repeats 1000000000", "at most 100 repeats"),
    ("render-steps-overlapping-ranges", "render ball --steps 0:4,2:6 --out {d}/r", "step(s) 2, 3 more than once"),
    ("render-spp-0", "render ball --spp 0 --out {d}/r", "--spp"),
    ("render-gt-spp-0", "render ball --gt-spp 0 --ground-truth --out {d}/r", "--gt-spp"),
    ("render-seed-negative", "render ball --seed -1 --out {d}/r", "--seed"),
    ("render-height-0", "render ball --height 0 --width 16 --out {d}/r", "--height"),
    ("render-height-without-width", "render ball --height 10 --out {d}/r", "--height and --width go together"),
    ("render-motion-missing", "render ball --motion {d}/missing.json --out {d}/r", "--motion"),
    ("render-motion-directory", "render ball --motion {d} --out {d}/r", "--motion"),
    ("render-lights-missing", "render ball --lights {d}/missing.json --out {d}/r", "--lights"),
    ("render-settings-missing", "render ball --render-settings {d}/missing.json --out {d}/r", "--render-settings"),
    ("render-settings-bad-json", "render ball --settings {d}/cam_bad.json --out {d}/r", "cam_bad.json"),
    ("render-exposure-unknown-key", "render ball --exposure {d}/cam_unknown.json --out {d}/r", "cam_unknown.json"),
    ("render-png-scale-0", "render ball --png-scale 0 --out {d}/r", "--png-scale"),
    ("render-png-scale-negative", "render ball --png-scale -1 --out {d}/r", "--png-scale"),
    ("render-png-scale-nan", "render ball --png-scale nan --out {d}/r", "--png-scale"),
    ("render-png-percentile-150", "render ball --png-percentile 150 --out {d}/r", "--png-percentile"),
    ("render-png-percentile-negative", "render ball --png-percentile -5 --out {d}/r", "--png-percentile"),
    ("render-out-is-file", "render ball --height 10 --width 16 --out {d}/good.npy", "--out"),
    # demo: everything is checked before any rendering starts
    ("demo-scene-unknown", "demo --scenes nosuch --out {d}/demo --quiet", "--scenes"),
    ("demo-scene-path", "demo --scenes ../x --out {d}/demo --quiet", "--scenes"),
    ("demo-scenes-none", "demo --scenes --out {d}/demo --quiet", "--scenes"),
    ("demo-windows-0", "demo --windows 0 --out {d}/demo --quiet", "--windows"),
    ("demo-workers-0", "demo --workers 0 --out {d}/demo --quiet", "--workers"),
    ("demo-workers-negative", "demo --workers -2 --out {d}/demo --quiet", "--workers"),
    ("demo-seed-negative", "demo --seed -1 --out {d}/demo --quiet", "--seed"),
    ("demo-checkpoint-missing", "demo --checkpoint {d}/missing.pt --out {d}/demo --quiet", "--checkpoint"),
    ("demo-checkpoint-directory", "demo --checkpoint {d} --out {d}/demo --quiet", "--checkpoint"),
    ("demo-out-is-file", "demo --out {d}/good.npy --quiet", "--out"),
    # tradeoff
    ("tradeoff-scene-unknown", "tradeoff --scenes nosuch -o {d}/t --quiet", "--scenes"),
    ("tradeoff-scene-path", "tradeoff --scenes ../x -o {d}/t --quiet", "--scenes"),
    ("tradeoff-height-0", "tradeoff --height 0 -o {d}/t --quiet", "--height"),
    ("tradeoff-width-small", "tradeoff --width 5 -o {d}/t --quiet", "--width"),
    ("tradeoff-height-text", "tradeoff --height abc -o {d}/t --quiet", "--height"),
    ("tradeoff-windows-0", "tradeoff --windows 0 -o {d}/t --quiet", "--windows"),
    ("tradeoff-windows-22", "tradeoff --windows 22 -o {d}/t --quiet", "--windows"),
    ("tradeoff-ref-spp-0", "tradeoff --ref-spp 0 -o {d}/t --quiet", "--ref-spp"),
    ("tradeoff-gt-spp-negative", "tradeoff --gt-spp -1 -o {d}/t --quiet", "--gt-spp"),
    ("tradeoff-repeats-0", "tradeoff --repeats 0 -o {d}/t --quiet", "--repeats"),
    ("tradeoff-seed-negative", "tradeoff --seed -1 -o {d}/t --quiet", "--seed"),
    ("tradeoff-report-only-empty", "tradeoff --report-only -o {d}/no_study --quiet", "no_study"),
    ("tradeoff-out-is-file", "tradeoff -o {d}/good.npy --quiet", "--out"),
    ("tradeoff-images-is-file", "tradeoff --images {d}/good.npy -o {d}/t --quiet", "--images"),
    # golden and the program itself
    ("golden-backend-unknown", "golden --backend opencl", "--backend"),
    ("command-unknown", "nosuchcommand", "nosuchcommand"),
]




def assert_one_error_line(err: str, names: str) -> None:
    """stderr ends in exactly one error line naming `names`; argparse's usage lines may precede it."""
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert lines, "nothing on stderr"
    errors = [line for line in lines if "error:" in line]
    assert errors == [lines[-1]], err
    assert names in lines[-1], err
    assert all(line.startswith(("usage:", " ")) for line in lines[:-1]), err


@pytest.mark.parametrize("argv, names", [pytest.param(a, n, id=i) for i, a, n in CASES])
def test_bad_input_ends_in_one_line(argv, names, bad, capsys):
    if "unreadable" in argv and os.geteuid() == 0:
        pytest.skip("root reads files whatever their mode")
    rc, err = run_cli(shlex.split(argv.format(d=bad)), capsys)
    assert rc == 2, err
    assert_one_error_line(err, names)


@pytest.mark.parametrize("argv", [["render", "ball"], ["simulate"], ["inspect", "s.dat"], ["generate", "llr", "-o", "d"]])
def test_an_unknown_option_is_refused_naming_the_command(argv, capsys):
    rc, err = run_cli([*argv, "--no-such-option"], capsys)
    assert rc == 2 and f"spikesim {argv[0]}: error: unrecognized arguments: --no-such-option" in err


def test_inspect_on_an_image_says_it_is_not_a_spike_stream(tmp_path, capsys):
    from spikesim.imageio import write_exr
    exr = tmp_path / "step_000000.exr"
    write_exr(exr, np.ones((4, 6), dtype=np.float32))
    rc, err = run_cli(["inspect", exr], capsys)
    line = one_line(err)
    assert rc == 2 and "OpenEXR image, not a spike stream" in line and "simulate --frames" in line


@pytest.mark.parametrize("line, says", [("threshold_electrons = 1e-300", "threshold_electrons=1e-300 is outside [10.0"),
                                        ("readout_period_s = 1e-12", "readout_period_s=1e-12 is outside [1e-07")])
def test_render_exposure_takes_the_cameras_ranges(line, says, tmp_path, capsys):
    """A threshold of 1e-300 rendered non-finite frames and blamed the scene; a 1e-12 s period
    rendered frames that simulate then refused (round nine)."""
    from pipelines.cli import main
    (tmp_path / "e.toml").write_text(line + "\n")
    assert main(["render", "fan", "--steps", "0", "--height", "16", "--width", "24", "--spp", "1", "--exposure",
                 str(tmp_path / "e.toml"), "--quiet", "-o", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert "e.toml" in err and says in err and not (tmp_path / "r").exists()

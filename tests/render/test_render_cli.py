"""The `render` subcommand: argument parsing, files written, exit codes."""
from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from render_testing import PLANE
from pipelines import render_cmd


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="spikesim")
    render_cmd.add_parser(ap.add_subparsers(dest="command", required=True))
    return ap


def test_parse_steps():
    assert render_cmd.parse_steps("0:3,10") == [0, 1, 2, 10]
    assert render_cmd.parse_steps("20:861:41")[:2] == [20, 61]
    with pytest.raises(argparse.ArgumentTypeError):
        render_cmd.parse_steps("a:b")
    with pytest.raises(argparse.ArgumentTypeError):
        render_cmd.parse_steps("-1")


def test_render_ground_truth_to_exr_and_png(make_scene, tmp_path):
    from spikesim.imageio import read_exr
    from spikesim.render import SceneRenderer

    xml = make_scene(PLANE.format(reflectance=0.5))
    out = tmp_path / "out"
    args = _parser().parse_args(["render", str(xml), "--steps", "0,5", "--ground-truth", "--gt-spp", "4",
                                 "--out", str(out)])
    assert args.func(args) == 0
    for step in (0, 5):
        assert (out / "gt" / f"step_{step:06d}.png").is_file()
        y = read_exr(out / "gt" / f"step_{step:06d}.exr")
        np.testing.assert_array_equal(y, SceneRenderer(xml, gt_spp=4).ground_truth(step))
    meta = json.loads((out / "render.json").read_text())
    assert meta["kind"] == "gt" and meta["steps"] == [0, 5] and meta["render"]["gt_spp"] == 4


def test_render_frames_and_bad_scene_exit_code(make_scene, tmp_path, capsys):
    xml = make_scene(PLANE.format(reflectance=0.5))
    args = _parser().parse_args(["render", str(xml), "--steps", "0:2", "--height", "10", "--width", "16", "--out", str(tmp_path)])
    assert args.func(args) == 0
    assert len(list((tmp_path / "frames").glob("*.exr"))) == 2
    from pipelines.cli import main
    assert main(["render", str(tmp_path / "missing.xml"), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("spikesim render: error: ") and "missing.xml" in err and len(err.splitlines()) == 1


def test_the_render_benchmark_never_writes_through_a_link(tmp_path):
    """python -m spikesim.render.benchmark --out goes through the output guard: a link there is
    refused before any measurement, and the file it points to is untouched."""
    from spikesim.render.benchmark import main as benchmark_main
    outside = tmp_path / "keep.json"
    outside.write_text("keep")
    (tmp_path / "results.json").symlink_to(outside)
    with pytest.raises(ValueError, match="is a symlink"):
        benchmark_main(["--only", "timing", "--out", str(tmp_path / "results.json")])
    assert outside.read_text() == "keep"

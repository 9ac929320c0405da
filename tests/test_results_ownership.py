"""Every command that writes its results into a folder it shares with the user keeps the record
of what it wrote there (`.spikesim-results.json`), and replaces only that: compare, demo and
tradeoff replaced a user's compare.md, metrics.md and tradeoff.md; a panel or golden file put
in place while the command ran was overwritten; outputs landed inside a dataset (round ten)."""
from __future__ import annotations

import json

import pytest

from cli_testing import one_line, run_cli


@pytest.fixture(scope="module")
def dat16(tmp_path_factory):
    import numpy as np
    from spikesim.stream import SpikeStream, write_dat
    rng = np.random.default_rng(3)
    spikes = rng.random((41 * 3, 16, 16)) < np.linspace(0.05, 0.6, 16)[None, None, :]
    return write_dat(tmp_path_factory.mktemp("dat16") / "p.dat", SpikeStream.from_bool(spikes))


def panel(dat, out, *extra):
    return ["panel", dat, "--height", 16, "--width", 16, "--methods", "tfp", "-o", out, "--device", "cpu", *extra]


def test_panel_checks_its_output_again_as_it_writes(dat16, tmp_path, capsys, monkeypatch):
    """A PNG the user puts at -o while the methods run is refused, not replaced."""
    from pipelines.cli import build_parser
    target = tmp_path / "p.png"
    # the command's own module namespace (another test may have reloaded pipelines.panel since)
    run_globals = build_parser().parse_args([str(a) for a in panel(dat16, target)]).func.__globals__
    real = run_globals["compose_panel"]

    def compose_then_user_writes(*a, **k):
        target.write_bytes(b"the user's picture")
        return real(*a, **k)

    monkeypatch.setitem(run_globals, "compose_panel", compose_then_user_writes)
    code, err = run_cli(panel(dat16, target), capsys)
    assert code == 2 and "holds p.png, which no earlier panel run wrote" in one_line(err), err
    assert target.read_bytes() == b"the user's picture"


def test_panel_refuses_a_stream_too_small_for_its_scores_naming_it(tmp_path, capsys):
    import numpy as np
    from spikesim.stream import SpikeStream, write_dat
    dat = write_dat(tmp_path / "tiny.dat", SpikeStream.from_bool(np.ones((41, 7, 3), bool)))
    code, err = run_cli(["panel", dat, "--height", 7, "--width", 3, "--methods", "tfp", "-o", tmp_path / "p.png",
                         "--device", "cpu"], capsys)
    assert code == 2 and "tiny.dat: a 7 x 3 stream" in err and "16 x 16" in err, err


def test_panel_refuses_an_output_inside_a_dataset(dat16, tmp_path, capsys):
    ds = tmp_path / "ds"
    (ds / "fan_low").mkdir(parents=True)
    (ds / "manifest.json").write_text(json.dumps({"scenes": {}}))
    code, err = run_cli(panel(dat16, ds / "fan_low" / "p.png"), capsys)
    assert code == 2 and "inside the dataset" in err, err
    assert not (ds / "fan_low" / "p.png").exists()


def test_a_folder_at_the_record_is_refused_before_the_work(dat16, tmp_path, capsys):
    """evaluate/panel wrote their results, then failed on the record, leaving files every rerun refused."""
    (tmp_path / ".spikesim-results.json").mkdir()
    code, err = run_cli(panel(dat16, tmp_path / "p.png"), capsys)
    assert code == 2 and "is not a regular file" in err, err
    assert not (tmp_path / "p.png").exists()


def test_golden_refuses_the_record_name_as_its_reference(tmp_path, capsys):
    code, err = run_cli(["golden", "--write", "--seeds", "1", "-o", tmp_path / ".spikesim-results.json"], capsys)
    assert code == 2 and "no golden result may take that name" in err, err
    assert not (tmp_path / ".spikesim-results.json").exists()


def test_golden_checks_its_reference_again_before_writing(tmp_path, capsys, monkeypatch):
    from spikesim import golden as golden_mod
    target = tmp_path / "ref.json"
    real = golden_mod.measure_reference

    def measure_then_user_writes(*a, **k):
        target.write_text('{"my": "own"}')
        return real(*a, **k)

    monkeypatch.setattr(golden_mod, "measure_reference", measure_then_user_writes)
    code, err = run_cli(["golden", "--write", "--seeds", "1", "-o", target], capsys)
    assert code == 2 and "holds ref.json, which no earlier golden run wrote" in err, err
    assert json.loads(target.read_text()) == {"my": "own"}


def test_tradeoff_refuses_a_users_table_and_image_before_any_run(tmp_path, capsys):
    out, images = tmp_path / "t", tmp_path / "im"
    out.mkdir()
    images.mkdir()
    (out / "tradeoff.md").write_text("mine")
    argv = ["tradeoff", "--scenes", "fan", "--light", "low", "--height", 16, "--width", 24, "--windows", 1,
            "--ref-spp", 2, "--gt-spp", 4, "--knobs", "noise", "--repeats", 1, "-o", out, "--quiet"]
    code, err = run_cli(argv, capsys)
    assert code == 2 and "holds tradeoff.md, which no earlier tradeoff run wrote" in err, err
    assert (out / "tradeoff.md").read_text() == "mine" and not (out / "runs").exists()
    (out / "tradeoff.md").unlink()
    (images / "tradeoff_pareto.png").write_text("x")
    code, err = run_cli([*argv, "--images", images], capsys)
    assert code == 2 and "holds tradeoff_pareto.png" in err and "--images" in err, err
    assert not (out / "runs").exists()


def test_demo_refuses_a_users_table_before_rendering(tmp_path, capsys):
    (tmp_path / "metrics.md").write_text("my notes")
    code, err = run_cli(["demo", "--scenes", "fan", "--windows", 1, "--no-model", "-o", tmp_path, "--quiet"], capsys)
    assert code == 2 and "holds metrics.md, which no earlier demo run wrote" in err, err
    assert (tmp_path / "metrics.md").read_text() == "my notes" and not (tmp_path / "llr").exists()


def test_demo_takes_the_overwrite_it_advises(tmp_path, capsys, monkeypatch):
    """A second demo with another --windows into one -o advised --overwrite, which demo lacked:
    demo now takes it and hands it to the generator as its rebuild of stale scenes."""
    import spikesim.generation as generation
    seen = {}

    class Stop(Exception):
        pass

    def fake_generate(jobs, root, **kw):
        seen.update(kw)
        raise Stop

    monkeypatch.setattr(generation, "generate", fake_generate)
    for extra, want in (([], False), (["--overwrite"], True)):
        with pytest.raises(Stop):
            from pipelines.cli import main
            main(["demo", "--scenes", "fan", "--windows", "1", "--no-model", "-o", str(tmp_path / "d"), "--quiet",
                  *extra])
        assert seen["overwrite_stale"] is want


def test_compare_refuses_a_users_table_and_an_out_inside_the_test_data(tmp_path, capsys):
    from test_targets_compare import _config, _write_dataset
    _write_dataset(tmp_path / "train", ["a_normal"], 0)
    _write_dataset(tmp_path / "test", ["c_low"], 10)
    e = _config(tmp_path / "e.json", "e")
    base = ["compare", "--data", tmp_path / "train", "--test-data", tmp_path / "test", "--configs", f"E={e}",
            "--seeds", "0", "1", "2", "--max-steps", "1", "--device", "cpu", "--quiet"]
    code, err = run_cli([*base, "--out", tmp_path / "test" / "cmp"], capsys)
    assert code == 2 and "inside the dataset" in err, err
    assert not (tmp_path / "test" / "cmp").exists()
    out = tmp_path / "cmp"
    out.mkdir()
    (out / "compare.md").write_text("mine")
    code, err = run_cli([*base, "--out", out], capsys)
    assert code == 2 and "holds compare.md, which no earlier compare run wrote" in err, err
    assert (out / "compare.md").read_text() == "mine" and not (out / "runs").exists()

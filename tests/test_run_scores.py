"""pipelines.run_scores: a comparison's runs scored as evaluate --dat and panel score them."""
from __future__ import annotations

import json
import shutil

import pytest

from pipelines.run_scores import main


def test_a_run_holding_the_shipped_weights_scores_as_the_shipped_network(tmp_path, capsys, shared_data):
    from model.pretrained import pretrained_path

    pair, real = shared_data / "spk2imgnet-sample", shared_data / "uhsr-real" / "uhsr_helicopter.dat"
    if not (pair.is_dir() and real.is_file()):
        pytest.skip(f"the Spk2ImgNet sample or the UHSR recording is not in {shared_data}")

    for seed in (0, 1):
        run = tmp_path / "runs" / "X" / f"seed{seed}"
        run.mkdir(parents=True)
        shutil.copy(pretrained_path("lrrep"), run / "last.pt")
    assert main([str(tmp_path), "--pair", str(pair / "203_part1_key_id151.dat"), str(pair / "203_part1_key_id151.png"),
                 "151", "0.6", "--real", str(real), "250", "250", "--baselines", "tfp", "lrrep", "--threads", "1"]) == 0
    doc = json.loads((tmp_path / "external.json").read_text())
    s = doc["summary"]
    for key in ("pair.psnr_aligned", "real.edge_to_noise", "real.flat_noise"):
        assert s["X"][key]["mean"] == pytest.approx(s["LR-Rep"][key]["mean"], rel=1e-6)
        assert s["X"][key]["n"] == 2 and s["X"][key]["std"] == pytest.approx(0.0, abs=1e-9)
    assert s["TFP"]["pair.psnr_aligned"]["mean"] == pytest.approx(23.16, abs=0.01)  # docs/model.md
    assert "| X |" in capsys.readouterr().out


def test_no_runs_is_an_error(tmp_path):
    with pytest.raises(SystemExit):
        main([str(tmp_path)])

"""Round twelve, H2: `gpu-campaign --work` replaced a user's state.json and replaced or deleted the
files in its logs/ (rc 0), and took a dataset folder as --work (state.json and logs/ written into
a dataset, which verify then reports). -o was refused when it held files the campaign did not
write; --work now is too, before anything is written. The refusals come before any stage runs; a
stage that does run is an injected failure (no Dr.Jit needed)."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from pipelines.gpu_campaign.stages import CAMPAIGN, is_campaign_state


def _main(capsys, *args: str) -> tuple[int, str]:
    from pipelines.cli import main

    rc = main(["gpu-campaign", "--dry-run", "--quiet", *args])
    return rc, capsys.readouterr().err.strip()


def _tree(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): "folder" if p.is_dir() else p.read_text(errors="replace")
            for p in sorted(folder.rglob("*"))}


def _refused(capsys, tmp_path: Path, work: Path, *names: str) -> str:
    before = _tree(work)
    out = tmp_path / "CO"
    rc, err = _main(capsys, "--stages", "bench_sensor", "--inject", "bench_sensor=fail", "--work", str(work),
                    "-o", str(out))
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert f"--work {work}" in err and all(n in err for n in names), err
    assert _tree(work) == before and not out.exists()  # nothing written, replaced or deleted
    return err


@pytest.fixture(autouse=True)
def _no_out(monkeypatch):
    monkeypatch.delenv("OUT", raising=False)


def test_the_testers_case_a_users_state_and_logs_are_left_alone(tmp_path, capsys):
    work = tmp_path / "wuser"
    (work / "logs").mkdir(parents=True)
    (work / "state.json").write_text('{"my": "state"}')
    (work / "logs" / "install.stdout").write_text("notes")
    (work / "logs" / "install.log").write_text("mine")
    err = _refused(capsys, tmp_path, work, str(work / "state.json"))
    assert "not a campaign's state" in err
    (work / "state.json").unlink()  # then the logs: the campaign's names, but no campaign's record
    err = _refused(capsys, tmp_path, work, str(work / "logs"), "install.log", "install.stdout")
    assert "no campaign's state.json" in err


@pytest.mark.parametrize("text", ["notes, not JSON", "[1, 2]", '{"schema": 1}', '{"schema": 1, "stages": {}}',
                                  '{"schema": true, "campaign": "spikesim gpu-campaign", "stages": {}}',
                                  '{"schema": 1, "mode": "cpu", "seed": 0, "stages": {}, "mine": 1}'])
def test_a_state_json_the_campaign_did_not_write_is_refused(text, tmp_path, capsys):
    work = tmp_path / "W"
    work.mkdir()
    (work / "state.json").write_text(text)
    _refused(capsys, tmp_path, work, str(work / "state.json"), "not a campaign's state")


def test_files_in_logs_that_are_not_the_campaigns_logs_are_refused(tmp_path, capsys):
    """Even beside a campaign's state.json: the user's install.txt is not the campaign's to keep."""
    work = tmp_path / "W"
    (work / "logs" / "sub").mkdir(parents=True)
    (work / "state.json").write_text(json.dumps({"schema": 1, "campaign": CAMPAIGN, "mode": "dry-run", "seed": 0,
                                                 "stages": {}}))
    (work / "logs" / "install.txt").write_text("mine")
    (work / "logs" / "train.log").write_text("the campaign's")
    _refused(capsys, tmp_path, work, "install.txt", "sub", "does not write")


def test_a_dataset_as_work_or_above_it_is_refused(tmp_path, capsys):
    data = tmp_path / "data"
    data.mkdir()
    (data / "manifest.json").write_text(json.dumps({"layout_version": 1, "scenes": {}}))
    for work in (data, data / "campaign"):
        rc, err = _main(capsys, "--stages", "bench_sensor", "--inject", "bench_sensor=fail", "--work", str(work),
                        "-o", str(tmp_path / "CO"))
        assert rc == 2 and f"--work {work}: inside the dataset" in err, err
    assert sorted(p.name for p in data.iterdir()) == ["manifest.json"]
    rc, err = _main(capsys, "--stages", "bench_sensor", "--inject", "bench_sensor=fail", "--work",
                    str(tmp_path / "W"), "-o", str(data / "out"))
    assert rc == 2 and f"-o {data / 'out'}: inside the dataset" in err, err
    assert sorted(p.name for p in data.iterdir()) == ["manifest.json"] and not (tmp_path / "W").exists()


def test_an_earlier_campaigns_work_folder_is_still_taken(tmp_path, capsys):
    """A new folder, the same folder again (its own state.json and logs), and a state.json written
    before the campaign named itself there (the keys it wrote then)."""
    work = tmp_path / "W"
    for i in range(2):
        rc, err = _main(capsys, "--stages", "bench_sensor", "--inject", "bench_sensor=fail", "--work", str(work),
                        "-o", str(tmp_path / f"CO{i}"))
        assert rc == 0, err
        state = json.loads((work / "state.json").read_text())
        assert is_campaign_state(state) and state["campaign"] == CAMPAIGN
        assert sorted(p.name for p in (work / "logs").iterdir()) == ["bench_sensor.log"]
    del state["campaign"]
    (work / "state.json").write_text(json.dumps(state))
    (work / "logs" / ".train.log.0123abcd.part").write_text("a killed call's temporary log")
    rc, err = _main(capsys, "--stages", "bench_sensor", "--inject", "bench_sensor=fail", "--work", str(work),
                    "-o", str(tmp_path / "CO2"))
    assert rc == 0, err


def test_a_call_killed_in_its_first_stage_leaves_a_work_folder_the_next_call_takes(tmp_path, monkeypatch):
    """The state.json is written before the first log, so the logs a killed first stage leaves are
    told to be the campaign's."""
    from pipelines.gpu_campaign import PROFILES, Options
    from pipelines.gpu_campaign import runner

    work = tmp_path / "W"

    def killed(*args, **kwargs):
        assert is_campaign_state(json.loads((work / "state.json").read_text()))
        (work / "logs" / "bench_sensor.log").write_text("partial")
        raise KeyboardInterrupt

    monkeypatch.setattr(runner, "_run_stage", killed)
    o = Options(out=tmp_path / "o", work=work, profile=PROFILES["dry-run"], part="all", stages=("bench_sensor",))
    with pytest.raises(KeyboardInterrupt):
        runner.run_campaign(o)
    runner.check_work_owner(work)  # accepted


def test_is_campaign_state():
    assert is_campaign_state({"schema": 1, "campaign": CAMPAIGN, "stages": {}})
    assert is_campaign_state({"schema": 1, "mode": "cpu", "seed": 0, "run_token": "ab", "stages": {}})
    for doc in ({"my": "state"}, [], None, {"schema": 1, "campaign": "other"}, {"schema": "1", "campaign": CAMPAIGN}):
        assert not is_campaign_state(doc)


def test_a_link_in_logs_is_refused(tmp_path, capsys):
    work = tmp_path / "W"
    (work / "logs").mkdir(parents=True)
    (tmp_path / "notes").write_text("mine")
    os.symlink(tmp_path / "notes", work / "logs" / "train.log")
    rc, err = _main(capsys, "--stages", "bench_sensor", "--inject", "bench_sensor=fail", "--work", str(work),
                    "-o", str(tmp_path / "CO"))
    assert rc == 2 and "symlink" in err and (tmp_path / "notes").read_text() == "mine", err

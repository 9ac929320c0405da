"""`spikesim gpu-campaign` against a hostile work folder (issue 30's surfaces, round two): a link
inside --work must not carry the campaign's writes, truncations or deletes outside it; a training
run the campaign did not make is never removed; a state.json that is a folder or a FIFO is refused
before any stage runs. The refusals come before anything runs, so these tests run no stage (a
stage that would run is replaced by an injected failure, which needs no Dr.Jit)."""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest

from pipelines.gpu_campaign import PROFILES, Options, StageRecord
from pipelines.gpu_campaign.stages import RUN_MARKER, Campaign, CommandResult, StageFailed, _checkpoint, stage_train


def _main(capsys, *args: str) -> tuple[int, str]:
    from pipelines.cli import main

    rc = main(["gpu-campaign", "--dry-run", "--quiet", *args])
    return rc, capsys.readouterr().err.strip()


def _tree(folder: Path) -> dict[str, str]:
    """Every entry under `folder` (links not followed): its kind, or a file's content."""
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = str(p.relative_to(folder))
        out[rel] = ("link " + os.readlink(p) if p.is_symlink() else "folder" if p.is_dir()
                    else p.read_text(errors="replace"))
    return out


# the link, relative to --work; where it points (a folder or file outside, or inside --work)
LINKS = [
    ("logs", "outside"),  # the tester's case: logs/ a link, its .stdout emptied and deleted outside
    ("logs/bench_sensor.stdout", "outside/bench_sensor.stdout"),
    ("logs/bench_sensor.log", "outside/bench_sensor.log"),
    ("state.json", "outside/state.json"),
    ("llr", "outside"), ("rllr", "outside"), ("run", "outside"), ("site", "outside"), ("export", "outside"),
    ("evaluate", "outside"), ("table1", "outside"),
    ("run", "WORK/elsewhere"),  # even a link that stays inside --work
]


@pytest.mark.parametrize("link,target", LINKS, ids=[f"{a}->{b}" for a, b in LINKS])
def test_a_link_inside_work_is_refused_before_anything_is_touched(link, target, tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("OUT", raising=False)
    outside, work, out = tmp_path / "outside", tmp_path / "W", tmp_path / "CO"
    outside.mkdir()
    (outside / "bench_sensor.stdout").write_text("keep")
    (outside / "state.json").write_text("keep")
    (work / "elsewhere").mkdir(parents=True)
    (work / link).parent.mkdir(parents=True, exist_ok=True)
    (work / link).symlink_to(Path(target.replace("WORK", str(work))) if target.startswith("WORK")
                             else tmp_path / target)
    before_outside, before_work = _tree(outside), _tree(work)
    rc, err = _main(capsys, "--stages", "bench_sensor", "--inject", "bench_sensor=fail", "--work", str(work),
                    "-o", str(out), "--deadline-minutes", "4")
    assert rc == 2, err
    assert len(err.splitlines()) == 1 and f"{work / link}: is a symlink" in err, err
    assert _tree(outside) == before_outside and _tree(work) == before_work
    assert not out.exists()  # refused before the output folder was made


def test_a_link_further_up_inside_work_is_refused(tmp_path, capsys, monkeypatch):
    """A link is refused wherever it sits on the way, not only at a file's own name."""
    monkeypatch.delenv("OUT", raising=False)
    work = tmp_path / "W"
    (work / "real_logs").mkdir(parents=True)
    (work / "logs").symlink_to(work / "real_logs")
    rc, err = _main(capsys, "--stages", "bench_sensor", "--inject", "bench_sensor=fail", "--work", str(work),
                    "-o", str(tmp_path / "CO"))
    assert rc == 2 and f"{work / 'logs'}: is a symlink" in err, err
    assert list((work / "real_logs").iterdir()) == []


@pytest.mark.parametrize("kind", ["folder", "FIFO"])
def test_a_state_json_that_is_not_a_file_is_refused_before_any_stage_runs(kind, tmp_path, capsys, monkeypatch):
    """A folder made the stages run, then rc 2 at the end ('is a directory'); a FIFO was ignored."""
    monkeypatch.delenv("OUT", raising=False)
    work = tmp_path / "W"
    work.mkdir()
    if kind == "folder":
        (work / "state.json").mkdir()
    else:
        os.mkfifo(work / "state.json")
    rc, err = _main(capsys, "--stages", "bench_sensor", "--inject", "bench_sensor=fail", "--work", str(work),
                    "-o", str(tmp_path / "CO"))
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert f"{work / 'state.json'}: is a {kind}" in err, err
    assert sorted(p.name for p in work.iterdir()) == ["state.json"]  # no stage ran: no logs/
    assert not (tmp_path / "CO").exists()


def test_a_log_of_the_wrong_kind_is_refused_before_any_stage_runs(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("OUT", raising=False)
    work = tmp_path / "W"
    (work / "logs" / "train.log").mkdir(parents=True)
    rc, err = _main(capsys, "--stages", "bench_sensor", "--inject", "bench_sensor=fail", "--work", str(work),
                    "-o", str(tmp_path / "CO"))
    assert rc == 2 and f"{work / 'logs' / 'train.log'}: is a folder" in err, err


def test_a_finished_run_the_campaign_did_not_train_is_never_removed(tmp_path, capsys, monkeypatch):
    """The tester's case: a state.json from an earlier call (bench_sensor only) beside a copied
    `spikesim train` run made the train stage delete the run (rc 0, 'skipped: no RLLR scene')."""
    monkeypatch.delenv("OUT", raising=False)
    work = tmp_path / "W"
    rc, err = _main(capsys, "--stages", "bench_sensor", "--inject", "bench_sensor=fail", "--work", str(work),
                    "-o", str(tmp_path / "CO1"))
    assert rc == 0 and (work / "state.json").is_file(), err
    run = work / "run"
    run.mkdir()
    for name, text in (("config.json", "{}"), ("last.pt", "weights"), ("train_log.csv", "step\n"),
                       ("NOTES.txt", "notes")):
        (run / name).write_text(text)
    before = _tree(run)
    out = tmp_path / "CO2"
    rc, err = _main(capsys, "--stages", "train", "--work", str(work), "-o", str(out))
    assert rc == 0, err
    stage = next(s for s in json.loads((out / "summary.json").read_text())["stages"] if s["name"] == "train")
    assert stage["status"] == "failed", stage
    assert "not an earlier campaign's training run" in stage["note"] and str(run) in stage["note"]
    assert _tree(run) == before


def _train_options(tmp_path: Path) -> Options:
    work = tmp_path / "W"
    (work / "rllr" / "scene_0000").mkdir(parents=True)
    (work / "rllr" / "scene_0000" / "meta.json").write_text("{}")
    return Options(out=tmp_path / "o", work=work, profile=PROFILES["dry-run"], part="all")


def _campaign(options: Options, calls: list) -> Campaign:
    """A campaign in its train stage whose `spikesim train` is replaced by a record of the call."""
    from pipelines.gpu_campaign.runner import _load_run_token

    c = Campaign(options)
    c.run_token = _load_run_token(options)
    c.current, c.box_end = StageRecord("train"), time.monotonic() + 100
    (options.work / "logs").mkdir(exist_ok=True)

    def spikesim(*args, box_s=None):
        calls.append(args)
        return CommandResult(0, False, 0.1, "{}")

    c.spikesim = spikesim
    return c


def test_the_campaign_removes_only_a_run_its_record_says_it_trained(tmp_path):
    o = _train_options(tmp_path)
    run, calls = o.work / "run", []
    stage_train(_campaign(o, calls))  # no run yet: made, with the token state.json records
    token = json.loads((o.work / "state.json").read_text())["run_token"]
    assert len(calls) == 1 and len(token) == 32 and (run / RUN_MARKER).read_text().strip() == token
    (run / "best.pt").write_text("an earlier call's weights")
    c = _campaign(o, calls)
    assert c.owns_run() and _checkpoint(c) == run / "best.pt"
    stage_train(c)  # this campaign's own run: trained afresh
    assert len(calls) == 2 and sorted(p.name for p in run.iterdir()) == [RUN_MARKER]

    (run / "best.pt").write_text("someone else's weights")  # a run copied from elsewhere: another token
    (run / RUN_MARKER).write_text("0" * 32)
    c = _campaign(o, calls)
    assert not c.owns_run() and _checkpoint(c) is None  # never evaluated or exported as this campaign's
    with pytest.raises(StageFailed, match="not an earlier campaign's training run"):
        stage_train(c)
    assert len(calls) == 2 and (run / "best.pt").read_text() == "someone else's weights"

    (run / RUN_MARKER).unlink()
    (run / RUN_MARKER).symlink_to(tmp_path / "token")  # a marker through a link is not a marker
    (tmp_path / "token").write_text(token)
    assert not _campaign(o, calls).owns_run()


def test_a_run_is_kept_when_training_cannot_start(tmp_path):
    """Even this campaign's own run stays until training is sure to start (was: removed, then
    'skipped: no RLLR scene')."""
    o = _train_options(tmp_path)
    calls: list = []
    stage_train(_campaign(o, calls))
    (o.work / "run" / "best.pt").write_text("weights")
    for scene in (o.work / "rllr").iterdir():
        (scene / "meta.json").unlink()
    from pipelines.gpu_campaign.stages import SkipStage
    with pytest.raises(SkipStage, match="left as it was"):
        stage_train(_campaign(o, calls))
    assert (o.work / "run" / "best.pt").read_text() == "weights" and len(calls) == 1

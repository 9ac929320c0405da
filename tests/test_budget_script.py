"""scripts/budget_run.sh (docs/model.md, "The budget run"): its commands, read from a dry run."""
from __future__ import annotations

import os
import shlex
import subprocess
from pathlib import Path

import pytest

from pipelines.gpu_campaign.options import BUDGET_DATA_VARIANTS, PROFILES

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "budget_run.sh"


def _dry_run(tmp_path: Path, data_variant: str = "", **extra: str) -> list[list[str]]:
    env = {**os.environ, "DRY_RUN": "1", "DATA": str(tmp_path / "d"), "RUNS": str(tmp_path / "r"),
           "DATA_VARIANT": data_variant, **extra}
    out = subprocess.run(["bash", str(SCRIPT)], env=env, capture_output=True, text=True, check=True, timeout=120)
    return [shlex.split(line) for line in out.stdout.splitlines() if not line.startswith("[budget]")
            and ("generate" in line or "torchrun" in line)]


def _values(argv: list[str], flag: str) -> list[str]:
    i = argv.index(flag) + 1
    out = []
    while i < len(argv) and not argv[i].startswith("-"):
        out.append(argv[i])
        i += 1
    return out


@pytest.fixture
def commands(tmp_path):
    if not (ROOT / ".venv" / "bin" / "python").exists():
        pytest.skip("the script runs the project's .venv")
    return _dry_run(tmp_path)


def test_the_data_are_the_campaigns_eight_sets_with_their_seeds(commands, tmp_path):
    generate = [c for c in commands if "generate" in c]
    made = {c[c.index("-o") + 1]: c[c.index("rllr") + 1:c.index("--workers")] for c in generate}
    want = {str(tmp_path / "d" / name): [a for a in _without_workers(args)]
            for name, _, args in PROFILES["gpu"].recipe_sets}
    assert made == want


def _without_workers(args: tuple[str, ...]) -> list[str]:
    """The arguments as the script passes them: without the campaign's --workers, where they have one."""
    a = list(args)
    if "--workers" not in a:
        return a
    i = a.index("--workers")
    return a[:i] + a[i + 2:]


def test_the_training_is_the_measured_run_from_a_random_draw(commands, tmp_path):
    (train,) = [c for c in commands if c[0].endswith("torchrun")]
    d = tmp_path / "d"
    # the order of the measured run (runs/scratch6h): the natural sets first
    assert _values(train, "--data") == [str(d / n) for n in (
        "rllr_nat8tr", "rllr_photo48", "rllr_photo_bright48", "rllr_photo_still48", "rllr_photo_bright_still48",
        "rllr_photo_vbright_still48")]
    assert _values(train, "--val-data") == [str(d / "val_nat8"), str(d / "val_photo8")]
    flags = {f: _values(train, f) for f in ("--config", "--lr", "--max-steps", "--seed", "-o")}
    assert flags == {"--config": ["lrrep_span"], "--lr": ["1e-3"], "--max-steps": ["9000"], "--seed": ["11"],
                     "-o": [str(tmp_path / "r" / "a")]}
    assert "--init" not in train and "--resume" not in train
    assert _values(train, "--nproc_per_node")[0] == "2" and _values(train, "--threads") == ["1"]
    assert "--keep-validated" in train  # the network can be picked by another rule afterwards


def test_a_stage_with_a_checkpoint_is_resumed_with_its_own_plan(tmp_path):
    if not (ROOT / ".venv" / "bin" / "python").exists():
        pytest.skip("the script runs the project's .venv")
    (tmp_path / "r" / "a").mkdir(parents=True)
    (tmp_path / "r" / "a" / "last.pt").write_bytes(b"")
    (train,) = [c for c in _dry_run(tmp_path) if c[0].endswith("torchrun")]
    assert "--resume" in train
    # the plan (lr, length, seed) comes from last.pt; the data flags must name the same data
    assert not {"--lr", "--max-steps", "--seed", "--init"} & set(train)
    assert len(_values(train, "--data")) == 6
    assert "--keep-validated" in train  # a run begun without it keeps the validations after the resume


def test_config_names_the_stage_a_config_and_nothing_else_moves(tmp_path, monkeypatch):
    """CONFIG=lrrep_span_shot (the loss lever's long run) changes the config alone: the data, plan
    and seed stay the measured run's, so the two runs differ by one factor."""
    if not (ROOT / ".venv" / "bin" / "python").exists():
        pytest.skip("the script runs the project's .venv")
    monkeypatch.delenv("CONFIG", raising=False)
    (base,) = [c for c in _dry_run(tmp_path) if c[0].endswith("torchrun")]
    monkeypatch.setenv("CONFIG", "lrrep_span_shot")
    (lever,) = [c for c in _dry_run(tmp_path) if c[0].endswith("torchrun")]
    i = base.index("--config") + 1
    assert lever[i] == "lrrep_span_shot" and base[i] == "lrrep_span"
    assert lever[:i] + lever[i + 1:] == base[:i] + base[i + 1:]


def test_every_share_a_budget_config_names_is_a_set_the_script_trains_on(commands):
    """A config's train.set_shares names sets by folder; one naming no --data root is refused only when
    the run starts. The budget configs' shares must name the script's training sets."""
    from model.config import load_config
    (train,) = [c for c in commands if c[0].endswith("torchrun")]
    trained = {Path(p).name for p in _values(train, "--data")}
    for name in ("lrrep_span", "lrrep_span_shot", "lrrep_span_shot_nat20", "lrrep_span_knee"):
        shares = load_config(name).train.set_shares or {}
        assert set(shares) <= trained, name
    assert load_config("lrrep_span_shot_nat20").train.set_shares


def test_the_cpu_time_it_prints_is_its_commands_not_a_subshells(tmp_path):
    """The script prints bash's `times` to compare with the budget. Piped (`times | tail -1`) it ran in
    a subshell and printed 0m0.000s after a 2-hour run; the commands' line must count what ran, and
    even a dry run runs a Python process (the list of sets)."""
    if not (ROOT / ".venv" / "bin" / "python").exists():
        pytest.skip("the script runs the project's .venv")
    env = {**os.environ, "DRY_RUN": "1", "DATA": str(tmp_path / "d"), "RUNS": str(tmp_path / "r")}
    out = subprocess.run(["bash", str(SCRIPT)], env=env, capture_output=True, text=True, check=True, timeout=120)
    lines = out.stdout.splitlines()
    i = next(k for k, line in enumerate(lines) if line.startswith("[budget] CPU time"))
    children = lines[i + 2].split()
    assert len(children) == 2 and children != ["0m0.000s", "0m0.000s"], lines[i:]


@pytest.mark.parametrize("variant", sorted(BUDGET_DATA_VARIANTS))
def test_a_data_variant_adds_its_sets_and_nothing_else_moves(tmp_path, variant):
    """DATA_VARIANT=NAME (natdark: the dark natural scenes' budget run; procedural: the first shipped
    model's kind of scenes) adds its training sets, made with their own seeds, natural sets first as
    the recipe orders them; the recipe's sets, the validation sets, the plan and the seed stay the
    measured run's, so the two runs differ by the data alone."""
    if not (ROOT / ".venv" / "bin" / "python").exists():
        pytest.skip("the script runs the project's .venv")
    base = _dry_run(tmp_path)
    added = _dry_run(tmp_path, variant)
    d = tmp_path / "d"
    variant_sets = BUDGET_DATA_VARIANTS[variant]
    assert all(role == "train" for _, role, _ in variant_sets)
    new_generate = [c for c in added if "generate" in c and c not in base]
    assert [c[c.index("-o") + 1] for c in new_generate] == [str(d / name) for name, _, _ in variant_sets]
    for command, (_, _, args) in zip(new_generate, variant_sets):
        assert command[command.index("rllr") + 1:command.index("--workers")] == _without_workers(args)
    (train0,) = [c for c in base if c[0].endswith("torchrun")]
    (train1,) = [c for c in added if c[0].endswith("torchrun")]
    data0, data1 = _values(train0, "--data"), _values(train1, "--data")
    new_paths = [str(d / name) for name, _, _ in variant_sets]
    assert [p for p in data1 if p not in new_paths] == data0 and set(new_paths) <= set(data1)
    natural_first = sorted(data1, key=lambda p: "_nat" not in Path(p).name)
    assert data1 == natural_first
    assert [a for a in train1 if a not in new_paths] == train0


def test_an_unknown_data_variant_stops_the_script_before_it_runs_anything(tmp_path):
    if not (ROOT / ".venv" / "bin" / "python").exists():
        pytest.skip("the script runs the project's .venv")
    env = {**os.environ, "DRY_RUN": "1", "DATA": str(tmp_path / "d"), "RUNS": str(tmp_path / "r"),
           "DATA_VARIANT": "natdrak"}
    out = subprocess.run(["bash", str(SCRIPT)], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode != 0
    assert "natdrak" in out.stderr and "natdark" in out.stderr
    assert "generate" not in out.stdout and "torchrun" not in out.stdout


def test_direct_steps_split_the_same_run_into_a_direct_stage_and_the_config_from_its_best(tmp_path, monkeypatch):
    """DIRECT_STEPS=5000 (the budget run with the direct network first): the first 5,000 of the 9,000
    steps train the config's direct twin from the random draw, the other 4,000 the config itself
    from that stage's best.pt; the data and validation sets stay the measured run's."""
    if not (ROOT / ".venv" / "bin" / "python").exists():
        pytest.skip("the script runs the project's .venv")
    monkeypatch.setenv("CONFIG", "lrrep_span_shot")
    (base,) = [c for c in _dry_run(tmp_path) if c[0].endswith("torchrun")]
    direct, refine = [c for c in _dry_run(tmp_path, DIRECT_STEPS="5000") if c[0].endswith("torchrun")]
    r = tmp_path / "r"
    flags = ("--config", "--lr", "--max-steps", "--seed", "--init", "-o")
    assert {f: _values(direct, f) for f in flags if f in direct} == {
        "--config": ["lrrep_span_shot_direct"], "--lr": ["1e-3"], "--max-steps": ["5000"], "--seed": ["11"],
        "-o": [str(r / "d")]}
    assert {f: _values(refine, f) for f in flags} == {
        "--config": ["lrrep_span_shot"], "--lr": ["3e-4"], "--max-steps": ["4000"], "--seed": ["12"],
        "--init": [str(r / "d" / "best.pt")], "-o": [str(r / "a")]}
    for stage in (direct, refine):
        assert _values(stage, "--data") == _values(base, "--data")
        assert _values(stage, "--val-data") == _values(base, "--val-data")


def test_the_direct_twin_is_the_config_with_the_direct_output_so_its_weights_widen():
    """`train --init` widens a direct network's head to the refining one only when the two model
    sections differ in the output alone (model.training.initial_weights); the twin must also train
    the same way, so the two stages differ by the head."""
    import dataclasses

    from model.config import load_config
    twin, target = load_config("lrrep_span_shot_direct"), load_config("lrrep_span_shot")
    assert twin.model.output == "direct" and target.model.output == "refine"
    assert dataclasses.replace(twin.model, output="refine", refine_span=target.model.refine_span) == target.model
    assert twin.train == target.train


@pytest.mark.parametrize("stages, extra", [
    (("d", "a"), {"DIRECT_STEPS": "5000", "CONFIG": "lrrep_span_shot"}),
    (("a", "h"), {"HEAD_STEPS": "1500", "CONFIG": "lrrep_span_shot_direct"})])
def test_every_stage_resumes_from_its_own_checkpoint(tmp_path, stages, extra):
    """A split run (d, a) and a run with the head stage (a, h): each stage with a last.pt resumes it,
    with its own recorded plan (no new flags, no --init)."""
    if not (ROOT / ".venv" / "bin" / "python").exists():
        pytest.skip("the script runs the project's .venv")
    for stage in stages:
        (tmp_path / "r" / stage).mkdir(parents=True)
        (tmp_path / "r" / stage / "last.pt").write_bytes(b"")
    trains = [c for c in _dry_run(tmp_path, **extra) if c[0].endswith("torchrun")]
    assert [_values(c, "-o") for c in trains] == [[str(tmp_path / "r" / s)] for s in stages]
    for c in trains:
        assert "--resume" in c and not {"--lr", "--max-steps", "--seed", "--init"} & set(c)


@pytest.mark.parametrize("variable, value, said", [
    *(("DIRECT_STEPS", v, "of the run's 9000") for v in ("0", "9000", "5k", "-1", "0100")),
    *(("TOTAL_STEPS", v, "from 2 to 100000") for v in ("0", "1", "9k", "0900", "100001")),
    *(("SEED", v, "from 0 to 1000000") for v in ("-1", "x", "011", "1000001"))])
def test_bad_step_counts_and_seeds_stop_the_script_before_it_runs_anything(tmp_path, variable, value, said):
    """A leading zero too ("0100"): bash's arithmetic reads it as octal, so DIRECT_STEPS=0100 would
    have trained 64 and 8,936 steps (and SEED=011 a refining stage of seed 10)."""
    if not (ROOT / ".venv" / "bin" / "python").exists():
        pytest.skip("the script runs the project's .venv")
    env = {**os.environ, "DRY_RUN": "1", "DATA": str(tmp_path / "d"), "RUNS": str(tmp_path / "r"), variable: value}
    out = subprocess.run(["bash", str(SCRIPT)], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    assert f"{variable}={value}" in out.stderr and said in out.stderr
    assert "generate" not in out.stdout and "torchrun" not in out.stdout


def test_total_steps_sets_the_runs_length_and_the_split_follows(tmp_path):
    """TOTAL_STEPS=11000: one stage of 11,000 steps; with DIRECT_STEPS=4000, 4,000 direct and 7,000
    refining. Nothing else moves."""
    if not (ROOT / ".venv" / "bin" / "python").exists():
        pytest.skip("the script runs the project's .venv")
    (base,) = [c for c in _dry_run(tmp_path, CONFIG="lrrep_span_shot") if c[0].endswith("torchrun")]
    (longer,) = [c for c in _dry_run(tmp_path, CONFIG="lrrep_span_shot", TOTAL_STEPS="11000")
                 if c[0].endswith("torchrun")]
    i = base.index("--max-steps") + 1
    assert base[i] == "9000" and longer[i] == "11000"
    assert longer[:i] + longer[i + 1:] == base[:i] + base[i + 1:]
    direct, refine = [c for c in _dry_run(tmp_path, CONFIG="lrrep_span_shot", TOTAL_STEPS="11000",
                                          DIRECT_STEPS="4000") if c[0].endswith("torchrun")]
    assert _values(direct, "--max-steps") == ["4000"] and _values(refine, "--max-steps") == ["7000"]


def test_a_direct_stage_without_its_config_stops_the_script_before_it_runs_anything(tmp_path):
    """CONFIG=lrrep_span has no direct twin: the script must say so before it makes any data."""
    if not (ROOT / ".venv" / "bin" / "python").exists():
        pytest.skip("the script runs the project's .venv")
    env = {**os.environ, "DRY_RUN": "1", "DATA": str(tmp_path / "d"), "RUNS": str(tmp_path / "r"),
           "CONFIG": "lrrep_span", "DIRECT_STEPS": "5000"}
    out = subprocess.run(["bash", str(SCRIPT)], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    assert "DIRECT_CONFIG=lrrep_span_direct" in out.stderr
    assert "generate" not in out.stdout and "torchrun" not in out.stdout


def test_seed_draws_another_run_and_nothing_else_moves(tmp_path):
    """SEED=5: the single stage (or the direct stage) takes seed 5, a refining stage 6; the measured
    runs' 11 and 12 by default."""
    if not (ROOT / ".venv" / "bin" / "python").exists():
        pytest.skip("the script runs the project's .venv")
    (base,) = [c for c in _dry_run(tmp_path) if c[0].endswith("torchrun")]
    (other,) = [c for c in _dry_run(tmp_path, SEED="5") if c[0].endswith("torchrun")]
    i = base.index("--seed") + 1
    assert base[i] == "11" and other[i] == "5"
    assert other[:i] + other[i + 1:] == base[:i] + base[i + 1:]
    direct, refine = [c for c in _dry_run(tmp_path, CONFIG="lrrep_span_shot", DIRECT_STEPS="4000", SEED="5")
                      if c[0].endswith("torchrun")]
    assert _values(direct, "--seed") == ["5"] and _values(refine, "--seed") == ["6"]


def _trains(tmp_path, **extra):
    return [c for c in _dry_run(tmp_path, **extra) if c[0].endswith("torchrun")]


def test_head_steps_add_the_head_on_the_frozen_body_from_the_networks_best(tmp_path):
    """HEAD_STEPS=1500 with the direct recipe (the measured run): the direct stage is as without it,
    then 1,500 steps of lrrep_span_shot_head from its best.pt, the next seed, the same data."""
    if not (ROOT / ".venv" / "bin" / "python").exists():
        pytest.skip("the script runs the project's .venv")
    recipe = {"CONFIG": "lrrep_span_shot_direct", "TOTAL_STEPS": "11000", "SEED": "21"}
    (alone,) = _trains(tmp_path, **recipe)
    direct, head = _trains(tmp_path, HEAD_STEPS="1500", **recipe)
    assert direct == alone
    r = tmp_path / "r"
    flags = ("--config", "--lr", "--max-steps", "--seed", "--init", "-o")
    assert {f: _values(head, f) for f in flags} == {
        "--config": ["lrrep_span_shot_head"], "--lr": ["1e-3"], "--max-steps": ["1500"], "--seed": ["22"],
        "--init": [str(r / "a" / "best.pt")], "-o": [str(r / "h")]}
    assert _values(head, "--data") == _values(direct, "--data")
    assert _values(head, "--val-data") == _values(direct, "--val-data")
    # after a split run the head stage takes the seed after the refining stage's
    *_, head = _trains(tmp_path, HEAD_STEPS="10", CONFIG="lrrep_span_shot", DIRECT_STEPS="100", SEED="5")
    assert _values(head, "--seed") == ["7"] and _values(head, "--config") == ["lrrep_span_shot_head"]


def test_the_head_configs_are_the_refining_config_with_the_body_frozen():
    """What the head stage trains differs from lrrep_span_shot by what it trains alone: the same
    network (so `--init` widens the direct network's head) and the same recipe."""
    import dataclasses

    from model.config import load_config
    full = load_config("lrrep_span_shot")
    for name, trainable in (("lrrep_span_shot_head", "head"), ("lrrep_span_shot_gates", "gates")):
        cfg = load_config(name)
        assert cfg.model == full.model
        assert cfg.train == dataclasses.replace(full.train, trainable=trainable)


@pytest.mark.parametrize("extra, said", [
    ({"HEAD_STEPS": "15x"}, "HEAD_STEPS=15x: expected a whole number"),
    ({"HEAD_STEPS": "0"}, "HEAD_STEPS=0: expected a whole number"),
    ({"HEAD_STEPS": "10", "HEAD_CONFIG": "nope"}, "HEAD_CONFIG=nope: no config"),
    ({"HEAD_STEPS": "10", "CONFIG": "lrrep_span_shot_direct", "HEAD_CONFIG": "lrrep_cpu"},
     "HEAD_CONFIG=lrrep_cpu: it trains every weight"),
    ({"HEAD_STEPS": "10", "CONFIG": "lrrep_span_shot_direct", "HEAD_CONFIG": "tiny"},
     "HEAD_CONFIG=tiny: its network is not CONFIG=lrrep_span_shot_direct's")])
def test_a_bad_head_stage_stops_the_script_before_it_runs_anything(tmp_path, extra, said):
    if not (ROOT / ".venv" / "bin" / "python").exists():
        pytest.skip("the script runs the project's .venv")
    env = {**os.environ, "DRY_RUN": "1", "DATA": str(tmp_path / "d"), "RUNS": str(tmp_path / "r"), **extra}
    out = subprocess.run(["bash", str(SCRIPT)], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    assert said in out.stderr
    assert "generate" not in out.stdout and "torchrun" not in out.stdout

"""What one GPU campaign is asked to do: its stages and parts, the profiles (`gpu` at the paper's
sizes, `dry-run` on the CPU at a tiny size) and the options of one invocation.

The default part is `one`: every stage in one device call of at most 9 minutes, in order of value
(the device budget is 15 minutes a task, the machine's start included, so a second call cannot
follow); parts `1` and `2` split them over two calls, and `all` runs them in stage order, for a
longer lease.

The bottom of the package (pipelines/gpu_campaign/): it imports nothing of the campaign, and the
stages (stages.py), the run (runner.py) and the command line (cmd.py) all read it.
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

#: The repository root: the stages run their commands from it, and the carried wheels lie in it.
ROOT = Path(__file__).resolve().parents[2]
STAGE_NAMES = ("install", "gpu_tests", "bench_sensor", "bench_render", "llr", "rllr", "train", "evaluate", "recipe",
               "export", "tradeoff", "table1")
PARTS = {
    # one call, in order of value: what only a GPU can measure first, then a short training and its
    # weights; gpu_tests, evaluate, the trade study's full-size points and table1 last, only where
    # time is left (OPTIONAL below)
    "one": ("install", "bench_sensor", "bench_render", "llr", "rllr", "train", "export", "gpu_tests", "evaluate",
            "tradeoff", "table1"),
    "1": ("install", "gpu_tests", "bench_sensor", "bench_render", "llr", "rllr", "tradeoff"),
    "2": ("install", "llr", "rllr", "train", "evaluate", "export", "table1"),
    "all": STAGE_NAMES,
    # the shipped network's recipe at GPU scale (RECIPE_CALL): its own call, the benches after it
    # only where time is left
    "recipe": ("install", "recipe", "export", "bench_sensor", "bench_render"),
}
DEFAULT_PART = "one"
#: Stages of a part that run only where time is left: no earlier stage keeps its least box for them.
#: table1 (the Table-1 networks at equal training FLOP) needs most of a call: in a part it runs
#: after everything else, where time is left; a call of its own (TABLE1_CALL) gives it its time.
OPTIONAL = {"one": ("gpu_tests", "evaluate", "tradeoff", "table1"), "1": ("tradeoff",), "2": ("table1",),
            "all": ("tradeoff", "table1"), "recipe": ("bench_sensor", "bench_render")}
#: The call that gives table1 its time on a lent GPU: part one's datasets, then table1 alone
#: (`--stages install llr rllr table1`, part `one`'s 540 s); `Profile.table1_call_plan_s` is its
#: time line. With a warm machine after part 1 (or 2), `--part 2 --stages table1` gives it 555 s.
TABLE1_CALL = ("one", ("install", "llr", "rllr", "table1"))
#: The call that gives the trade study's full-size points their time (`spikesim tradeoff` at 400 x 250
#: on the GPU, all five LLR scenes under both lights, resumable: a later call goes on where the box
#: cut it): `--stages install tradeoff`, part `one`'s 540 s.
TRADEOFF_CALL = ("one", ("install", "tradeoff"))
#: The call that trains the shipped network's recipe at GPU scale (stage recipe: its six training
#: sets and two validation sets made on the GPU from the commands of docs/model.md, then `lrrep_span`
#: fine-tuned from the shipped `lrrep` at a larger batch and crop) and hands its weights back
#: (`recipe_weights.pt`), to be scored off the GPU on the held-out sets: part `recipe`, 540 s.
RECIPE_CALL = ("recipe", ("install", "recipe", "export", "bench_sensor", "bench_render"))
#: Seconds a call of each part may take by default (`--deadline-minutes`): a device call is killed
#: at 600; part `one` leaves 60 of them for a stage's grace (20 s), the last writes and the start.
PART_DEADLINE_S = {"one": 540.0, "1": 555.0, "2": 555.0, "all": 555.0, "recipe": 540.0}
#: Stages whose data a later call reuses instead of measuring again (resumable datasets).
DATA_STAGES = ("llr", "rllr")
INJECTIONS = ("fail", "timeout")


# ---- what a campaign runs at which size ---------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Profile:
    """The sizes, devices and time boxes of one kind of campaign: `gpu` (the paper's sizes on
    CUDA) or `dry-run` (the same commands on the CPU at a tiny size, to rehearse them)."""

    name: str
    drjit_device: str
    """Where `generate` and `bench` render and simulate: cuda or llvm."""
    torch_device: str
    """Where `train` and `evaluate` run: cuda or cpu."""
    needs_gpu: bool
    """Whether the install stage fails when torch or Dr.Jit sees no CUDA device."""
    bench_sensor: tuple[str, ...]
    bench_render: tuple[str, ...]
    llr: tuple[str, ...]
    rllr: tuple[str, ...]
    rllr_count: int
    """RLLR scenes to make (the paper has 100; the time for 100 is extrapolated)."""
    tradeoff: tuple[str, ...]
    """Stage tradeoff's `spikesim tradeoff` options (the study's scenes, size, reference and knobs)."""
    tradeoff_report_s: float
    """Seconds stage tradeoff keeps, when the study's box cuts it, to write the report of what is cached."""
    train: tuple[str, ...]
    evaluate: tuple[str, ...]
    train_config: str
    train_overhead_s: float
    """Seconds of a training stage's box that are not training steps: start-up, validation, saving."""
    train_max_minutes: float | None
    llr_windows: int
    """Windows per LLR sequence: `tfp:N` takes N = windows x 41 steps (a network sees as much)."""
    boxes: dict[str, tuple[float, float]]
    """Per stage (least seconds worth starting it with, most seconds it may take)."""
    part_boxes: dict[str, dict[str, tuple[float, float]]]
    """Per part, the boxes that differ from `boxes` (part `one` fits every stage in one call)."""
    part_rllr_count: dict[str, int]
    """Per part, RLLR scenes to make where it differs from `rllr_count`."""
    part_plan_s: dict[str, dict[str, float]]
    """Per part, the seconds each stage is planned to take (docs/gpu_campaign.md's time line; the
    tests check that it fits the boxes and the part's deadline)."""
    catch_up_s: dict[str, float]
    """Most seconds a later call spends remaking a dataset the machine lost between calls."""
    grace_s: float
    """Seconds between SIGTERM and SIGKILL when a stage's box ends (train writes last.pt)."""
    table1: tuple[tuple[str, str], ...] = ()
    """Stage table1's networks, (label, config) in training order: the first that trains is the
    reference whose steps, planned from the time left, set the training FLOP of all of them."""
    table1_train: tuple[str, ...] = ()
    """Arguments every table1 `train` takes besides the stage's own (the dry run's tiny crop and K)."""
    table1_overhead_s: float = 30.0
    """Seconds of each table1 training run that are not steps: start-up, data, the last validation, saving."""
    table1_eval_s: float = 60.0
    """Seconds table1 keeps for scoring every trained network on the LLR (one `evaluate`)."""
    table1_max_minutes: float | None = None
    """At most this many minutes of steps per table1 network (the dry run keeps its test short)."""
    table1_call_plan_s: dict[str, float] = dataclasses.field(default_factory=dict)
    """The seconds each stage of TABLE1_CALL is planned to take (the tests check that it fits the
    boxes and part `one`'s deadline); empty where the profile has no such plan."""
    recipe_sets: tuple[tuple[str, str, tuple[str, ...]], ...] = ()
    """Stage recipe's datasets, made in this order: (name, role "train" or "val", `generate rllr`
    options). best.pt is chosen on the "val" ones."""
    recipe_train: tuple[str, ...] = ()
    """Stage recipe's `train` options (config, --init, the batch, crop, rate and loaders at this scale)."""
    recipe_config: str = "lrrep_span"
    recipe_seed: int = 9
    """The training seed of stage recipe (the CPU runs of the sixth stage used 7 and 8)."""
    recipe_train_least_s: float = 180.0
    """Seconds of stage recipe's box that making the data leaves to training (a set is skipped, or
    cut with its complete scenes kept, so that training keeps them)."""
    recipe_set_least_s: float = 10.0
    """A set is started only with this many seconds left before training's share."""
    recipe_overhead_s: float = 45.0
    """Seconds of recipe training that are not steps: start-up, validations, saving."""
    recipe_max_minutes: float | None = None

    def boxes_of(self, part: str) -> dict[str, tuple[float, float]]:
        """Every stage's (least, most) seconds in a call of `part`."""
        return {**self.boxes, **self.part_boxes.get(part, {})}

    def __post_init__(self) -> None:
        if self.drjit_device not in ("cuda", "llvm") or self.torch_device not in ("cuda", "cpu"):
            raise ValueError(f"profile {self.name}: devices {self.drjit_device}/{self.torch_device}")
        if set(self.boxes) != set(STAGE_NAMES):
            raise ValueError(f"profile {self.name}: time boxes for {sorted(self.boxes)}, expected {STAGE_NAMES}")
        for part, boxes in {"": self.boxes, **self.part_boxes}.items():
            if part and (part not in PARTS or not set(boxes) <= set(STAGE_NAMES)):
                raise ValueError(f"profile {self.name}: part {part!r}: boxes for {sorted(boxes)}")
            for stage, (least, most) in boxes.items():
                if not 0 < least <= most:
                    raise ValueError(f"profile {self.name}: stage {stage}: box ({least}, {most}) must have "
                                     "0 < least <= most")
        if not set(self.part_plan_s) <= set(PARTS) or any(not set(p) <= set(STAGE_NAMES)
                                                          for p in self.part_plan_s.values()):
            raise ValueError(f"profile {self.name}: part_plan_s for {sorted(self.part_plan_s)}")
        if not set(self.part_rllr_count) <= set(PARTS) or min(self.part_rllr_count.values(), default=1) < 1:
            raise ValueError(f"profile {self.name}: part_rllr_count {self.part_rllr_count}")
        if self.rllr_count < 1 or self.llr_windows < 1 or self.grace_s < 0 or self.train_overhead_s < 0:
            raise ValueError(f"profile {self.name}: counts must be positive, times non-negative")
        labels = [label for label, _ in self.table1]
        if not labels or len(set(labels)) != len(labels) or self.table1_overhead_s < 0 or self.table1_eval_s < 0:
            raise ValueError(f"profile {self.name}: table1 needs networks with unique labels and non-negative times")
        if not set(self.table1_call_plan_s) <= set(TABLE1_CALL[1]):
            raise ValueError(f"profile {self.name}: table1_call_plan_s for {sorted(self.table1_call_plan_s)}")
        names = [n for n, _, _ in self.recipe_sets]
        if (not any(role == "train" for _, role, _ in self.recipe_sets) or len(set(names)) != len(names)
                or not all(n.replace("_", "").isalnum() for n in names)
                or not all(role in ("train", "val") for _, role, _ in self.recipe_sets)):
            raise ValueError(f"profile {self.name}: recipe needs training sets with unique plain names and roles "
                             f"'train' or 'val', got {[(n, r) for n, r, _ in self.recipe_sets]}")
        if min(self.recipe_train_least_s, self.recipe_set_least_s, self.recipe_overhead_s) < 0:
            raise ValueError(f"profile {self.name}: recipe times must be non-negative")


_TINY = ("--height", "16", "--width", "24", "--workers", "1", "--quality", "balanced")
# The sixth stage's data (docs/model.md, "The sixth stage"), with the same seeds, made on the GPU:
# five photo sets (panning and still cameras, dark to saturation) and eight rendered natural scenes,
# validated on eight natural and eight photo scenes of their own seeds
_RLLR = ("--preset", "paper", "--steps", "369", "--gt-stride", "41")
_PHOTO = (*_RLLR, "--content", "photo", "--workers", "8")
_NATURAL = (*_RLLR, "--content", "natural", "--spp", "2", "--gt-spp", "48", "--darkening", "log-uniform", "--workers", "4")
_SCALES = ("--scales", "1", "0.5", "0.25")
_SIXTH_STAGE_SETS = (
    ("val_photo8", "val", (*_PHOTO, "--scales", "0.5", "--count", "8", "--darkening", "log-uniform", "--seed", "401")),
    ("rllr_photo48", "train", (*_PHOTO, *_SCALES, "--count", "48", "--darkening", "log-uniform", "--seed", "400")),
    ("rllr_photo_bright48", "train", (*_PHOTO, *_SCALES, "--count", "48", "--darkening", "uniform", "--peak-y", "2",
                                      "--seed", "403")),
    ("rllr_photo_still48", "train", (*_PHOTO, *_SCALES, "--still-share", "1", "--count", "48", "--darkening",
                                     "log-uniform", "--seed", "404")),
    ("rllr_photo_bright_still48", "train", (*_PHOTO, *_SCALES, "--still-share", "1", "--count", "48", "--darkening",
                                            "uniform", "--peak-y", "2", "--seed", "405")),
    ("rllr_photo_vbright_still48", "train", (*_PHOTO, *_SCALES, "--still-share", "1", "--count", "48", "--darkening",
                                             "uniform", "--peak-y", "3", "--seed", "406")),
    ("val_nat8", "val", (*_NATURAL, "--scales", "0.5", "--count", "8", "--seed", "301")),
    ("rllr_nat8tr", "train", (*_NATURAL, *_SCALES, "--count", "8", "--seed", "300")),
)
#: Training sets that a CPU budget run (scripts/budget_run.sh, DATA_VARIANT=NAME) adds to the recipe's,
#: each measured as one factor against the run without it (docs/model.md).
#: "natdark": 24 rendered natural scenes under dim lamps (10-100 lx at the subject before the
#: log-uniform darkening, so 0.05-100 lx): the budget data hold 8 natural scenes, 4 of them below
#: y 1e-3, and three budget runs learned no structure in the darkest held-out natural scenes.
#: Measured with lrrep_span_shot and not kept: held-out natural 24.37 against 25.94 without it.
#: "procedural": lrrep_v1's kind of scenes, measured with lrrep_span_shot_direct over 11,000 steps, two
#: seeds: the darkest held-out natural scene 17.14 and 17.18 dB against 15.33 and 15.00 without it,
#: the natural set 26.63 and 26.47 against 26.27 and 26.13 (docs/model.md, "The first model's kind of data").
BUDGET_DATA_VARIANTS: dict[str, tuple[tuple[str, str, tuple[str, ...]], ...]] = {
    "natdark": (("rllr_natdark24", "train", (*_NATURAL, *_SCALES, "--lamps-lux", "10", "100", "--count", "24",
                                             "--seed", "310")),),
    # "procedural": the first shipped model's kind of data (lrrep_v1, which holds the darkest held-out
    # natural scene that the budget runs lose): 40 procedural scenes (30-250 lx lamps, log-uniform
    # darkening, so 0.15-250 lx), at the recipe's scales and ground-truth samples
    "procedural": (("rllr_proc40", "train", (*_RLLR, "--content", "procedural", "--spp", "2", "--gt-spp", "48",
                                             "--darkening", "log-uniform", *_SCALES, "--count", "40",
                                             "--seed", "320")),),
}
PROFILES: dict[str, Profile] = {
    "gpu": Profile(
        "gpu", "cuda", "cuda", True,
        bench_sensor=("--stages", "sensor", "--backends", "cuda", "--streams", "8", "--steps", "2048",
                      "--numpy-steps", "128"),
        bench_render=("--stages", "render", "pipeline", "--backends", "cuda", "--repeats", "2"),
        llr=("--preset", "paper", "--quality", "balanced"),
        rllr=("--preset", "paper", "--quality", "balanced"),
        rllr_count=10,
        # the 400 x 250 study the `fast` quality was chosen from (spikesim.preset_rule.STUDY_CSV)
        tradeoff=("--scenes", "ball", "car", "cook", "fan", "rotate", "--light", "low", "normal", "--height", "250",
                  "--width", "400", "--windows", "5", "--ref-spp", "32", "--gt-spp", "128", "--knobs", "spp", "seeds",
                  "--gt-error-spp", "16", "64"),
        tradeoff_report_s=60.0,
        # 8 loader processes of the 16 cores: a sample is 21 windows of spikes and 21 ground-truth
        # EXR files, read and cropped on the CPU
        train=("--config", "full", "--num-workers", "8"),
        evaluate=(),
        train_config="full", train_overhead_s=75.0, train_max_minutes=None, llr_windows=21,
        # the measurements first, each capped so that at worst they leave the LLR two minutes; the
        # RLLR slice and training take what is left of their call
        boxes={"install": (30, 90), "gpu_tests": (30, 120), "bench_sensor": (30, 90), "bench_render": (30, 90),
               "llr": (60, 240), "rllr": (60, 600), "train": (150, 3600), "evaluate": (90, 180),
               "recipe": (240, 3600), "export": (15, 60), "tradeoff": (120, 3600), "table1": (150, 3600)},
        # part `one` (docs/gpu_campaign.md, "On the GPU: one call of 9 minutes"): the expected seconds of docs/gpu_campaign.md
        # (install 15-30, bench_sensor 30-60, bench_render 20-40, LLR under 2 min) as the mosts, so
        # that even when every stage before training uses its whole box (60 + 60 + 45 + 135 + 90 =
        # 390 s) training keeps its least (120 s) and export its own (15 s) within the 540 s; the
        # RLLR slice is one or two scenes in 60-90 s; training takes what is left but export's least
        part_boxes={"one": {"install": (30, 60), "bench_sensor": (20, 60), "bench_render": (20, 45),
                            "llr": (60, 135), "rllr": (60, 90), "train": (120, 3600), "export": (15, 60)},
                    # RECIPE_CALL: install (24.5 s on the first GPU), then the recipe takes all but
                    # export's least; the benches only where time is left
                    "recipe": {"install": (30, 60), "recipe": (240, 3600), "export": (10, 60),
                               "bench_sensor": (20, 60), "bench_render": (20, 45)}},
        part_rllr_count={"one": 2},
        # the time line: the expected seconds above (mid-range, the LLR at its 2-minute goal, one RLLR
        # scene at a pace that fits 75 s), training then given what is left of 540 but export's least
        # (540 - 300 - 15 = 225 s of box, of which 220 used), 5 s for the writes between stages
        part_plan_s={"one": {"install": 30, "bench_sensor": 45, "bench_render": 30, "llr": 120, "rllr": 75,
                             "train": 220, "export": 15},
                     # the data in at most 320 s (the rest of the box but training's least), training
                     # in what is left; export in seconds
                     "recipe": {"install": 30, "recipe": 490, "export": 10}},
        # a bare machine in part 2 (the first call's datasets lost): the LLR (under 2 min is the
        # goal) and 1-3 RLLR scenes, which leaves training about 3 minutes
        catch_up_s={"llr": 150, "rllr": 90}, grace_s=20.0,
        # Table 1 at its published sizes (model/configs: 2.2-5.6 M parameters, 0.25-2.1 TFLOP per
        # 400 x 250 frame), `full` first: its steps in the budget set the training FLOP of all five
        table1=(("full", "full"), ("s2i", "s2i"), ("wgse", "wgse"), ("rsir", "rsir"), ("ssml", "ssml")),
        table1_train=("--num-workers", "8"),
        # estimates until a GPU has run them: a training process's CUDA start, the slice's scenes,
        # one validation of 4 samples at 400 x 250 and the saving; one `evaluate` of five networks
        # on the LLR's 10 sequences of 21 windows
        table1_overhead_s=30.0, table1_eval_s=75.0,
        # TABLE1_CALL in part one's 540 s: the datasets at part one's plan, then table1 takes what
        # is left (540 - 225 - 5 s of writes = 310 s of box): 15 s of cost count, 5 x 30 s of
        # overheads, 75 s of scoring and 5 x 12 s of steps (85 % of their 14 s share)
        table1_call_plan_s={"install": 30, "llr": 120, "rllr": 75, "table1": 305},
        # the shipped network's recipe at GPU scale: its weights (--init lrrep), its config (since the
        # budget run shipped, lrrep_span_shot: the same network, the loss weighted by 1/sqrt(light)) and
        # schedule, on the sixth stage's eight sets, four times the batch and twice the crop side (16 x
        # more pixels a step), the rate doubled (the square root of the batch's factor), fp32 as on the
        # CPU, 8 loader processes
        recipe_sets=_SIXTH_STAGE_SETS,
        recipe_train=("--config", "lrrep_span_shot", "--init", "lrrep", "--lr", "2e-4", "--batch-size", "32",
                      "--crop", "48", "--num-workers", "8", "--precision", "fp32", "--lr-schedule", "cosine"),
        recipe_seed=9, recipe_train_least_s=180.0, recipe_set_least_s=10.0, recipe_overhead_s=45.0),
    "dry-run": Profile(
        "dry-run", "llvm", "cpu", False,
        bench_sensor=("--stages", "sensor", "--backends", "llvm", "--streams", "2", "--height", "16", "--width", "24",
                      "--steps", "64", "--numpy-steps", "8", "--repeats", "1"),
        bench_render=("--stages", "render", "pipeline", "--backends", "llvm", "--height", "16", "--width", "24",
                      "--spp", "1", "--repeats", "1", "--pipeline-steps", "17"),
        llr=("--preset", "small", "--scenes", "fan", "--windows", "3", *_TINY),
        rllr=("--preset", "small", *_TINY),
        rllr_count=2,
        tradeoff=("--scenes", "fan", "--light", "low", "--height", "16", "--width", "24", "--windows", "1",
                  "--ref-spp", "2", "--gt-spp", "4", "--knobs", "spp", "--gt-error-spp", "2", "--repeats", "1",
                  "--threads", "1"),
        tradeoff_report_s=20.0,
        # one torch thread: on a shared CPU, OpenMP's barriers between two threads that wait for
        # cores made steps of 0.2 s take 4-17 s (measured on the development VM)
        train=("--config", "tiny", "--crop", "16", "--max-steps", "20", "--threads", "1"),
        evaluate=("--threads", "1"),
        train_config="tiny", train_overhead_s=10.0, train_max_minutes=0.1, llr_windows=3,
        boxes={"install": (5, 60), "gpu_tests": (5, 120), "bench_sensor": (5, 120), "bench_render": (5, 120),
               "llr": (5, 180), "rllr": (5, 180), "train": (10, 180), "evaluate": (5, 120), "export": (2, 60),
               "recipe": (30, 300), "tradeoff": (30, 180), "table1": (30, 240)},
        part_boxes={}, part_rllr_count={}, part_plan_s={},
        catch_up_s={"llr": 180, "rllr": 180}, grace_s=5.0,
        # the same five rows at the tiny size: `tiny` for the paper's network, the published ones at
        # the shipped network's compute (cpu_*), all on the dry run's 16 x 24 frames, K = 3
        table1=(("full", "tiny"), ("s2i", "cpu_s2i"), ("wgse", "cpu_wgse"), ("rsir", "cpu_rsir"),
                ("ssml", "cpu_ssml")),
        table1_train=("--crop", "16", "--num-windows", "3", "--batch-size", "4", "--threads", "1"),
        table1_overhead_s=6.0, table1_eval_s=20.0, table1_max_minutes=0.02,
        # measured on the loaded 2-core VM (2026-11-26): 10 s of cost count, 5-7 s a training
        # process, 6 s of scoring: 47 s
        table1_call_plan_s={"install": 5, "llr": 5, "rllr": 8, "table1": 50},
        # the same recipe at the tiny size: a photo and a natural training set, a photo validation set
        # (6 windows: the network's span is 5), the shipped weights fine-tuned for a few steps
        recipe_sets=(
            ("val_photo1", "val", ("--preset", "small", "--height", "16", "--width", "24", "--steps", "246",
                                   "--gt-stride", "41", "--content", "photo", "--scales", "1", "--count", "1",
                                   "--seed", "401", "--workers", "1")),
            ("rllr_photo2", "train", ("--preset", "small", "--height", "16", "--width", "24", "--steps", "246",
                                      "--gt-stride", "41", "--content", "photo", "--scales", "1", "--count", "2",
                                      "--darkening", "log-uniform", "--seed", "400", "--workers", "1")),
            ("rllr_nat1", "train", ("--preset", "small", "--height", "16", "--width", "24", "--steps", "246",
                                    "--gt-stride", "41", "--content", "natural", "--scales", "1", "--count", "1",
                                    "--spp", "1", "--gt-spp", "2", "--seed", "300", "--workers", "1"))),
        recipe_train=("--config", "lrrep_span_shot", "--init", "lrrep", "--crop", "16", "--batch-size", "2",
                      "--max-steps", "4", "--threads", "1", "--precision", "fp32", "--lr-schedule", "cosine"),
        recipe_seed=9, recipe_train_least_s=20.0, recipe_set_least_s=2.0, recipe_overhead_s=10.0,
        recipe_max_minutes=0.1),
}


@dataclasses.dataclass(frozen=True)
class Options:
    """One invocation of the campaign."""

    out: Path
    work: Path
    profile: Profile
    part: str = DEFAULT_PART
    stages: tuple[str, ...] = ()
    """Only these of the part's stages (empty: all of them)."""
    deadline_s: float | None = None
    """Seconds this invocation may take in all (a device call is killed at 600); None: the part's
    default (PART_DEADLINE_S: 540 for part `one`)."""
    wheels: Path = ROOT / ".whl"
    seed: int = 0
    rllr_count: int | None = None
    inject: dict[str, str] = dataclasses.field(default_factory=dict)
    """Stage -> "fail" or "timeout": that stage's work is replaced by a failure (to test the campaign)."""
    fresh: bool = False
    """Forget the records of earlier calls (by default a call keeps them: part 2 adds to part 1)."""

    def __post_init__(self) -> None:
        if self.part not in PARTS:
            raise ValueError(f"--part {self.part!r}: expected one of {', '.join(PARTS)}")
        unknown = [s for s in self.stages if s not in PARTS[self.part]]
        if unknown:
            raise ValueError(f"--stages {' '.join(unknown)}: not stages of part {self.part} "
                             f"({', '.join(PARTS[self.part])})")
        for stage, what in self.inject.items():
            if stage not in STAGE_NAMES or what not in INJECTIONS:
                raise ValueError(f"--inject {stage}={what}: expected STAGE=fail or STAGE=timeout, STAGE one of "
                                 f"{', '.join(STAGE_NAMES)}")
        if self.deadline_s is None:
            object.__setattr__(self, "deadline_s", PART_DEADLINE_S[self.part])
        if not (math.isfinite(self.deadline_s) and self.deadline_s > 0):
            raise ValueError(f"the deadline must be a positive number of seconds, got {self.deadline_s}")
        if self.rllr_count is not None and self.rllr_count < 1:
            raise ValueError(f"--rllr-count must be >= 1, got {self.rllr_count}")
        out, work = self.out.resolve(), self.work.resolve()
        if out == work or work in out.parents or out in work.parents:
            raise ValueError(f"--out {self.out} and --work {self.work} must be separate folders (the output holds "
                             "only what comes back)")

    @property
    def selected(self) -> tuple[str, ...]:
        return tuple(s for s in PARTS[self.part] if not self.stages or s in self.stages)

    @property
    def boxes(self) -> dict[str, tuple[float, float]]:
        """Every stage's (least, most) seconds in this call: the profile's, with its part's overrides."""
        return self.profile.boxes_of(self.part)

    @property
    def optional(self) -> tuple[str, ...]:
        """The stages of this call that run only where time is left (no earlier stage keeps time for them)."""
        return OPTIONAL.get(self.part, ())

    @property
    def rllr_target(self) -> int:
        """RLLR scenes to make: --rllr-count, else the profile's for this part."""
        return self.rllr_count or self.profile.part_rllr_count.get(self.part, self.profile.rllr_count)


__all__ = ["ROOT", "STAGE_NAMES", "PARTS", "DEFAULT_PART", "OPTIONAL", "TABLE1_CALL", "TRADEOFF_CALL", "RECIPE_CALL", "PART_DEADLINE_S", "DATA_STAGES",
           "INJECTIONS", "Profile", "PROFILES", "Options"]

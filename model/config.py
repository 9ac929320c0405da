"""Validated configuration: the network (ModelConfig), the training recipe (TrainConfig) and the
named experiment files in model/configs/*.json that pair them (package data, read through
importlib.resources so that a wheel install finds them too).

Defaults are the paper's (section Implementation Details) and the authors' released network
(docs/design.md section 5); every ablation is a field, so a named config is data, never a code edit.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from importlib import resources
from pathlib import Path
from typing import Any

from .precision import PRECISIONS
from .representations import INTERVAL_TRANSFORMS

CONFIG_DIR = resources.files(__package__) / "configs"  # the named configs, shipped in the package

REPRESENTATIONS = ("lr_rep", "spike", "tfp", "tfi", "ast", "amim", "sali", "wgse1d")
INTERVALS = ("gisi", "lisi")
LR_SCHEDULES = ("multistep", "cosine")
OUTPUTS = ("direct", "refine")
#: What a run trains: every weight, the head alone, or the refining head's gates alone
#: (model/arch.py, trainable_parameters).
TRAINABLE = ("all", "head", "gates")
#: The widest span the refining head averages over (windows): beyond it a still scene is rare.
MAX_REFINE_SPAN = 21
INPUT_NORMS = ("none", "window_rate")
#: The least floor of input_norm: a gain of at most 10^6. Below about 1e-38 a float32 floor is 0 and
#: an all-dark window divides 0 by 0 (NaN frames, round twenty-one).
MIN_INPUT_NORM_FLOOR_RATE = 1e-6
DEFORM_BACKENDS = ("auto", "torch", "torchvision")


#: Bounds on the network's size fields, far beyond any network trained here (the paper's: 64
#: features, 16 blocks, 41-step windows): a config or checkpoint asking for 10^6 blocks is damaged
#: or hostile, and building it would run until killed. model.arch.check_model_size also bounds the
#: weights' memory as a whole.
MAX_FEATURES, MAX_BLOCKS, MAX_WINDOW, MAX_PAD_MULTIPLE = 4096, 1024, 4095, 1024
#: Bound on the recipe's counts (epochs, steps, samples per epoch): far past any run, inside the
#: How far the shares of train.set_shares may add up past 1 (or short of it) by rounding alone.
SHARE_TOLERANCE = 1e-9
#: 64-bit indices torch and NumPy take (a larger count overflowed them with a traceback).
MAX_COUNT = 2 ** 62


def _int_in(value: Any, low: int, high: int) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and low <= value <= high


def _require(cond: bool, msg: str) -> None:
    if not cond:
        raise ValueError(msg)


def _from_dict(cls: type, data: dict[str, Any], where: str) -> Any:
    """Build a dataclass from a dict, naming unknown keys instead of ignoring them."""
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected a JSON object, got {type(data).__name__}")
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"{where}: unknown field(s) {unknown}; known fields: {sorted(known)}")
    kwargs = {k: (tuple(v) if isinstance(v, list) else v) for k, v in data.items()}
    return cls(**kwargs)


@dataclass(frozen=True)
class ModelConfig:
    """The reconstruction network. Paper model (E) = the defaults.

    representation: "lr_rep" (LR-Rep: spike branch + interval branch + attention), "spike" (the
      spike-window branch alone: "without LR-Rep"), "tfp" / "tfi" (that map through a conv in
      LR-Rep's place, paper Table 3), or a published method's representation in LR-Rep's place
      (paper Table 3, model/published_reps.py): "ast" (RSIR), "amim" (SSML), "sali" (Spk2ImgNet),
      "wgse1d" (WGSE).
    interval: "gisi" (carried across windows) or "lisi" (window-local), for lr_rep only.
    interval_transform: "raw" (authors) or "inverse" (1/interval) before the interval branch.
    adf: adjacent deep temporal features, i.e. the recurrent state carried between windows; off,
      each window is fused with a zero state (same weights, no propagation).
    aif: PCD alignment of the carried state (needs adf).
    output: "direct" (the paper's: the head's one channel is the frame) or "refine" (the head also
      gives two per-pixel gates, and the frame is g * classic + (1 - g) * network, classic = m * TFP
      + (1 - m) * TFI of the window itself: a plain window average costs the network nothing to
      reproduce where it is right; model/arch.py, refine).
    refine_span: windows (odd) whose mean spike rate, centred on the window, is a third classic
      estimate for "refine" (a third gate picks between it and the window's own TFP); 1 = off.
      Why: where the scene is still, the average over several windows (TFP-205 at 5 x 41 steps)
      beats any one window's estimate (docs/model.md, "The fifth stage").
    input_norm: "none", or "window_rate": each window's inputs (its spikes and, with the "inverse"
      interval transform, its 1/GISI map) are divided by the window's mean firing rate (spikes per
      step over its pixels), and the network's frame is multiplied by it again, so the features see
      one brightness whatever the light and brightness is not something the weights must learn
      (model/arch.py, window_rate_scale). The classic estimates of "refine" are not scaled.
    input_norm_floor_rate: the least rate (spikes per step) the window's mean is taken as, so a
      window with almost no spikes is not amplified without bound: 1e-3, one spike per pixel in
      1,000 steps, bounds the gain at 1,000.
    """

    arch: str = "lrrep_bidirectional"
    window: int = 41
    num_features: int = 64
    num_blocks: int = 16
    representation: str = "lr_rep"
    interval: str = "gisi"
    interval_transform: str = "raw"
    adf: bool = True
    aif: bool = True
    deform_groups: int = 8
    deform_backend: str = "auto"
    pad_multiple: int = 4
    output: str = "direct"
    refine_span: int = 1
    input_norm: str = "none"
    input_norm_floor_rate: float = 1e-3

    def __post_init__(self) -> None:
        _require(self.input_norm in INPUT_NORMS, f"model.input_norm must be one of {INPUT_NORMS}, got {self.input_norm!r}")
        _require(isinstance(self.input_norm_floor_rate, (int, float)) and not isinstance(self.input_norm_floor_rate, bool)
                 and MIN_INPUT_NORM_FLOOR_RATE <= self.input_norm_floor_rate <= 1,
                 f"model.input_norm_floor_rate must be a rate in [{MIN_INPUT_NORM_FLOOR_RATE:g}, 1] spikes per step, "
                 f"got {self.input_norm_floor_rate!r}")
        _require(self.input_norm == "none" or self.representation in ("lr_rep", "spike")
                 and (self.representation == "spike" or self.interval_transform == "inverse"),
                 f"model.input_norm={self.input_norm!r} scales rate-like inputs: it needs representation 'lr_rep' "
                 f"with interval_transform 'inverse' (1/interval is a rate) or 'spike', got representation="
                 f"{self.representation!r}, interval_transform={self.interval_transform!r}")
        _require(self.output in OUTPUTS, f"model.output must be one of {OUTPUTS}, got {self.output!r}")
        _require(_int_in(self.refine_span, 1, MAX_REFINE_SPAN) and self.refine_span % 2 == 1,
                 f"model.refine_span must be an odd integer in 1..{MAX_REFINE_SPAN} (windows), got {self.refine_span!r}")
        _require(self.refine_span == 1 or self.output == "refine",
                 f"model.refine_span={self.refine_span} needs model.output 'refine' (it feeds the refining head)")
        _require(_int_in(self.window, 1, MAX_WINDOW) and self.window % 2 == 1,
                 f"model.window must be an odd integer in 1..{MAX_WINDOW} (2*dt+1), got {self.window!r}")
        _require(_int_in(self.num_features, 1, MAX_FEATURES),
                 f"model.num_features must be an integer in 1..{MAX_FEATURES}, got {self.num_features!r}")
        _require(_int_in(self.num_blocks, 0, MAX_BLOCKS),
                 f"model.num_blocks must be an integer in 0..{MAX_BLOCKS}, got {self.num_blocks!r}")
        _require(self.representation in REPRESENTATIONS,
                 f"model.representation must be one of {REPRESENTATIONS}, got {self.representation!r}")
        _require(self.interval in INTERVALS, f"model.interval must be one of {INTERVALS}, got {self.interval!r}")
        _require(self.interval_transform in INTERVAL_TRANSFORMS,
                 f"model.interval_transform must be one of {INTERVAL_TRANSFORMS}, got {self.interval_transform!r}")
        _require(isinstance(self.adf, bool) and isinstance(self.aif, bool), "model.adf and model.aif must be booleans")
        _require(not self.aif or self.adf, "model.aif=true needs model.adf=true: alignment acts on the carried state")
        _require(isinstance(self.deform_groups, int) and self.deform_groups >= 1
                 and self.num_features % self.deform_groups == 0,
                 f"model.deform_groups={self.deform_groups!r} must be >= 1 and divide num_features={self.num_features}")
        _require(self.deform_backend in DEFORM_BACKENDS,
                 f"model.deform_backend must be one of {DEFORM_BACKENDS}, got {self.deform_backend!r}")
        _require(_int_in(self.pad_multiple, 4, MAX_PAD_MULTIPLE) and self.pad_multiple % 4 == 0,
                 f"model.pad_multiple must be a multiple of 4 (two stride-2 pyramid levels), got {self.pad_multiple!r}")

    @property
    def decode_needs_window(self) -> bool:
        """Whether decoding a window needs its spikes: the refining head's classic estimates, or the
        firing rate the frame is scaled back by (input_norm)."""
        return self.output == "refine" or self.input_norm != "none"

    @property
    def carries_spike_times(self) -> bool:
        """Whether inputs of one window depend on spikes in other windows (GISI)."""
        return self.representation == "lr_rep" and self.interval == "gisi"

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "ModelConfig":
        return _from_dict(cls, data, "model config")


@dataclass(frozen=True)
class TrainConfig:
    """The training recipe; defaults are the paper's (section 5.1).

    samples_per_epoch: None = every (scene, start) sample of the training split once per epoch.
    start_stride: spacing in steps between the first window centres of samples drawn from one
      scene (1 = every step that has ground truth).
    val_fraction / val_scenes: the validation split (scene names win over the fraction).
    val_crop: centre crop for validation PSNR (None = full frames).
    precision: "auto" (bf16 autocast on a GPU that supports it, fp16 on an older one, fp32 on the
      CPU), "bf16", "fp16" (autocast with a GradScaler) or "fp32" (model/precision.py). Configs
      written before it had `amp` (true: "auto", false: "fp32"), still read.
    lr_schedule: "multistep" (the paper's: x lr_gamma at each epoch of lr_milestones) or "cosine"
      (per step, from lr down to lr * lr_final_ratio at the run's last step: max_steps, the steps a
      budget allows, or every epoch's batches).
    channels_last: keep the weights (so the activations) in the channels-last memory format, which
      oneDNN's CPU convolutions run faster (docs/model.md, "A model for two CPU cores"); the
      arithmetic is the same.
    budget_minutes: a wall-clock budget for the training steps. The run measures its step rate over
      its first calibration_steps steps, plans the number of steps that fits the budget, records it
      in its checkpoints (a resumed run keeps the same plan, so the same schedule) and ends there;
      with "cosine" the decay ends at the budget. max_steps, when also given, caps the plan.
    set_shares: the share of each epoch's samples drawn from a training dataset, by its folder name
      (the prefix of its scenes' names when --data gives several roots), e.g. {"rllr_nat8tr": 0.2};
      the sets it does not name share what is left in proportion to their samples. None: every
      (scene, start) sample alike, so a set's share is its share of the samples (model/data.py,
      set_probabilities).
    trainable: "all" (every weight), "head" (the head's convs alone, on the frozen body's features)
      or "gates" (only the refining head's gate channels: the rows of the head's last conv that
      give the gates; the body and the network's own frame stay as the run's --init gave them, bit
      for bit; model.output must be "refine"). Why: a direct network widened with gates
      (widen_head_state) can learn where a classic estimate beats its frame without its body being
      retrained, so what the direct network holds (the darkest scenes) is not given back.
    """

    num_windows: int = 21
    crop: int = 64
    batch_size: int = 8
    epochs: int = 100
    lr: float = 1e-4
    betas: tuple[float, float] = (0.9, 0.99)
    lr_milestones: tuple[int, ...] = (70,)
    lr_gamma: float = 0.1
    loss: str = "l1_sum"
    samples_per_epoch: int | None = None
    start_stride: int = 1
    val_fraction: float = 0.1
    val_scenes: tuple[str, ...] = ()
    val_crop: int | None = None
    val_max_samples: int = 4
    val_every: int = 1
    min_validations: int = 10
    """Validate at least this many times over a run: where val_every epochs would give fewer (a
    run of few, short epochs, such as `tiny`'s one-step epochs), the cadence becomes the run's
    epochs / min_validations, so best.pt is chosen from the run and not just its last step."""
    ckpt_every: int = 1
    keep_validated: bool = False
    """Also keep the checkpoint of every validation (validated/step_NNNNNN.pt beside the per-scene
    scores of val_scenes.csv), so that a rule other than the mean (the worst scene's score, one
    set's mean) can pick the run's network afterwards (`spikesim pick-checkpoint`)."""
    ckpt_every_steps: int | None = None
    """Also write last.pt every this many steps, so a run cut anywhere loses at most that many."""
    max_steps: int | None = None
    num_workers: int = 0
    precision: str = "auto"
    grad_clip: float | None = None
    seed: int = 0
    lr_schedule: str = "multistep"
    lr_final_ratio: float = 0.01
    channels_last: bool = False
    budget_minutes: float | None = None
    calibration_steps: int = 10
    set_shares: dict[str, float] | None = None
    trainable: str = "all"

    def __post_init__(self) -> None:
        def pos_int(name: str, allow_none: bool = False) -> None:
            v = getattr(self, name)
            if allow_none and v is None:
                return
            _require(isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= MAX_COUNT,
                     f"train.{name} must be a positive integer (at most 2**62), got {v!r}")
        for name in ("num_windows", "crop", "batch_size", "epochs", "start_stride", "val_max_samples",
                     "val_every", "min_validations", "ckpt_every"):
            pos_int(name)
        for name in ("samples_per_epoch", "val_crop", "max_steps", "ckpt_every_steps"):
            pos_int(name, allow_none=True)
        _require(self.crop % 4 == 0, f"train.crop must be divisible by 4 (PCD pyramid), got {self.crop}")
        _require(isinstance(self.lr, (int, float)) and not isinstance(self.lr, bool) and math.isfinite(self.lr)
                 and 0 < self.lr <= 1, f"train.lr must be a number in (0, 1], got {self.lr!r}")
        _require(len(self.betas) == 2 and all(0 <= b < 1 for b in self.betas),
                 f"train.betas must be two numbers in [0, 1), got {self.betas}")
        _require(all(isinstance(m, int) and 0 < m for m in self.lr_milestones)
                 and list(self.lr_milestones) == sorted(self.lr_milestones),
                 f"train.lr_milestones must be increasing positive epochs, got {self.lr_milestones}")
        _require(0 < self.lr_gamma <= 1, f"train.lr_gamma must be in (0, 1], got {self.lr_gamma}")
        _require(0 <= self.val_fraction < 1, f"train.val_fraction must be in [0, 1), got {self.val_fraction}")
        _require(isinstance(self.num_workers, int) and self.num_workers >= 0,
                 f"train.num_workers must be an integer >= 0, got {self.num_workers!r}")
        _require(self.grad_clip is None or self.grad_clip > 0, f"train.grad_clip must be > 0, got {self.grad_clip}")
        _require(isinstance(self.seed, int) and not isinstance(self.seed, bool) and 0 <= self.seed <= 2 ** 63 - 1,
                 f"train.seed must be an integer in 0..2**63 - 1 (torch seeds with 64 bits), got {self.seed!r}")
        _require(self.precision in PRECISIONS, f"train.precision must be one of {PRECISIONS}, got {self.precision!r}")
        _require(self.lr_schedule in LR_SCHEDULES,
                 f"train.lr_schedule must be one of {LR_SCHEDULES}, got {self.lr_schedule!r}")
        _require(isinstance(self.lr_final_ratio, (int, float)) and 0 <= self.lr_final_ratio <= 1,
                 f"train.lr_final_ratio must be in [0, 1], got {self.lr_final_ratio!r}")
        _require(self.budget_minutes is None or (isinstance(self.budget_minutes, (int, float))
                                                 and not isinstance(self.budget_minutes, bool)
                                                 and 0 < self.budget_minutes <= 60 * 24 * 365),
                 f"train.budget_minutes must be a positive number of minutes (at most a year), got {self.budget_minutes!r}")
        pos_int("calibration_steps")
        _require(isinstance(self.channels_last, bool), f"train.channels_last must be a boolean, got {self.channels_last!r}")
        _require(isinstance(self.keep_validated, bool), f"train.keep_validated must be a boolean, got {self.keep_validated!r}")
        _require(self.trainable in TRAINABLE, f"train.trainable must be one of {TRAINABLE}, got {self.trainable!r}")
        if self.set_shares is not None:
            shares = self.set_shares
            _require(isinstance(shares, dict) and bool(shares),
                     f"train.set_shares must be an object of dataset folder names and shares, got {shares!r}")
            for name, share in shares.items():
                _require(isinstance(name, str) and bool(name) and ":" not in name and "/" not in name,
                         f"train.set_shares: {name!r} is not a dataset folder name (the prefix of its scenes' names)")
                _require(isinstance(share, (int, float)) and not isinstance(share, bool) and math.isfinite(share)
                         and 0 < share <= 1, f"train.set_shares[{name!r}] must be a share in (0, 1], got {share!r}")
            total = math.fsum(shares.values())
            _require(total <= 1 + SHARE_TOLERANCE,
                     f"train.set_shares add up to {total:g}, more than every sample (1): lower them")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "TrainConfig":
        if isinstance(data, dict) and "amp" in data:  # written before `precision` (checkpoints, configs)
            data = dict(data)
            amp = data.pop("amp")
            if not isinstance(amp, bool):
                raise ValueError(f"train config: amp must be a boolean, got {amp!r}")
            data.setdefault("precision", "auto" if amp else "fp32")
        return _from_dict(cls, data, "train config")


@dataclass(frozen=True)
class ExperimentConfig:
    """One named config file: {"name", "description", "model": {...}, "train": {...}}."""

    name: str
    description: str = ""
    model: ModelConfig = field(default_factory=ModelConfig)
    train: TrainConfig = field(default_factory=TrainConfig)

    def __post_init__(self) -> None:
        name = self.name
        _require(self.train.trainable != "gates" or self.model.output == "refine",
                 f"train.trainable='gates' trains the refining head's gates: it needs model.output 'refine', "
                 f"got {self.model.output!r}")
        _require(isinstance(name, str) and bool(name) and not name.startswith(".")
                 and not any(c in name for c in "/\\\0"),
                 f"config name {name!r} must be a plain name (no path separators, not starting with a dot): "
                 "it names the run's folder")

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "description": self.description,
                "model": self.model.to_dict(), "train": self.train.to_dict()}

    @classmethod
    def from_dict(cls, data: dict[str, Any], where: str = "config") -> "ExperimentConfig":
        if not isinstance(data, dict):
            raise ValueError(f"{where}: expected a JSON object, got {type(data).__name__}")
        from spikesim.config_io import check_numbers
        check_numbers(data, where)  # also a checkpoint's stored config: no 400-digit integer reaches math.isfinite
        unknown = sorted(set(data) - {"name", "description", "model", "train"})
        if unknown:
            raise ValueError(f"{where}: unknown top-level field(s) {unknown}")
        if "name" not in data:
            raise ValueError(f"{where}: missing 'name'")
        if not isinstance(data["name"], str):
            raise ValueError(f"{where}: name must be a string, got {data['name']!r}")
        try:
            return cls(name=data["name"], description=str(data.get("description", "")),
                       model=ModelConfig.from_dict(data.get("model", {})),
                       train=TrainConfig.from_dict(data.get("train", {})))
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None


def available_configs() -> list[str]:
    """Names of the configs shipped in model/configs/."""
    return sorted(p.name[:-len(".json")] for p in CONFIG_DIR.iterdir() if p.name.endswith(".json"))


#: How many configs a chain of "base" may pass through (a -> b -> c ...): far more than any study needs;
#: a longer chain is a loop or a damaged file.
MAX_BASE_DEPTH = 8


def _config_path(name_or_path: str | Path) -> Path:
    p = Path(name_or_path)
    if not (p.suffix == ".json" and p.exists()):
        p = CONFIG_DIR / f"{name_or_path}.json"
    if not p.exists():  # a FIFO or device named *.json is refused by the reader, not called missing
        raise FileNotFoundError(f"no config {str(name_or_path)!r}: not a JSON file and not one of "
                                f"{available_configs()} in {CONFIG_DIR}")
    return p


def _read_with_base(p: Path, chain: tuple[str, ...] = ()) -> dict[str, Any]:
    """A config's dictionary with its "base" resolved: the base config's model and train sections,
    each overridden field by field by this file's. A study's variants are then one or two fields on
    top of the network they vary (cpu_ablation_a = lrrep_cpu with the spike branch alone)."""
    from spikesim.config_io import read_json_file
    data = read_json_file(p, "config")  # a regular file, small, valid JSON, numbers finite and sane
    if not isinstance(data, dict) or "base" not in data:
        return data
    base = data["base"]
    if not isinstance(base, str) or not base:
        raise ValueError(f"{p}: \"base\" must name a config (a shipped name or a JSON file), got {base!r}")
    key = str(p.resolve())
    if key in chain or len(chain) >= MAX_BASE_DEPTH:
        raise ValueError(f"{p}: \"base\" chain {' -> '.join(chain + (key,))} loops or is longer than "
                         f"{MAX_BASE_DEPTH} configs")
    # a file is taken relative to this config's folder (never the folder the command runs in: what a
    # config means must not depend on it); any other value names a shipped config
    if base.endswith(".json"):
        target = p.parent / base
        if not (target.exists() or target.is_symlink()):
            raise ValueError(f"{p}: \"base\" {base!r} is not a file beside it ({target} does not exist)")
    else:
        if any(c in base for c in "/\\") or base.startswith("."):
            raise ValueError(f"{p}: \"base\" {base!r}: a shipped config is a plain name; a file is named with its "
                             ".json, relative to this config's folder")
        target = CONFIG_DIR / f"{base}.json"
        if not target.exists():
            raise ValueError(f"{p}: \"base\" {base!r} names no shipped config (known: {', '.join(available_configs())}); "
                             "a file is named with its .json, relative to this config's folder")
    parent = _read_with_base(Path(target), chain + (key,))
    merged = {k: v for k, v in parent.items() if k not in ("name", "description")}
    for k, v in data.items():
        if k == "base":
            continue
        if k in ("model", "train") and isinstance(v, dict) and isinstance(merged.get(k), dict):
            merged[k] = {**merged[k], **v}
        else:
            merged[k] = v
    return merged


def load_config(name_or_path: str | Path) -> ExperimentConfig:
    """Load a named config ("full", "tiny", ...) or a JSON file path; a "base" key names a config
    whose model and train fields this one starts from (resolved at load: a checkpoint stores the
    whole result)."""
    p = _config_path(name_or_path)
    data = _read_with_base(p)
    experiment = ExperimentConfig.from_dict(data, where=str(p))
    if "model" not in data:  # every named config has one: without it the default network trains silently
        raise ValueError(f"{p}: no \"model\" section: a config names the network it trains (arch, num_features, "
                         "num_blocks, ...; model/configs/full.json has every field); add one, \"model\": {} for "
                         "the paper's defaults")
    return experiment

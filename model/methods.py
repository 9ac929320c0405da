"""Reconstruction methods behind one interface, for the evaluate and reconstruct pipelines:
the TFP and TFI baselines, the traditional STP and SNM (model/classic_methods.py) and any trained
checkpoint, each turning windows into frames."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Protocol

import torch

from .checkpoint import for_inference, model_from_checkpoint
from .classic_methods import CLASSIC_METHODS, classic_method
from .representations import tfi_windows, tfp_windows
from .arch import ReconNet
from .streaming import WindowSource, default_horizon_stride, horizon_reconstruct, stream_reconstruct


class Method(Protocol):
    name: str
    window: int

    def frames(self, source: WindowSource) -> Iterator[tuple[int, torch.Tensor]]:
        """(window index, float32 (H, W) on the y scale) for every window of the source, in order."""
        ...


def black_windows(windows: torch.Tensor) -> torch.Tensor:
    """The floor every table shows: an all-black image, whatever the spikes."""
    return torch.zeros(windows.shape[:1] + windows.shape[2:], dtype=torch.float32)


def mean_windows(windows: torch.Tensor) -> torch.Tensor:
    """A constant image at the window's mean firing rate: right overall light, no structure."""
    rate = tfp_windows(windows).mean(dim=(-2, -1), keepdim=True)
    return rate.expand(windows.shape[:1] + windows.shape[2:]).contiguous()


#: Images without structure, the floor every table shows.
FLOORS = ("black", "mean")

#: Methods that map each window to an image on its own: the paper's baselines and two floors.
MAP_METHODS = {"tfp": tfp_windows, "tfi": tfi_windows, "black": black_windows, "mean": mean_windows}

@dataclass
class MapMethod:
    """TFP or TFI of each window on its own (the paper's baselines), or a trivial floor, `chunk`
    windows at a time (each window's map is its own, so the frames do not depend on it)."""

    name: str
    kind: str  # a key of MAP_METHODS
    window: int = 41
    # windows held at once: 64 held 2.9 GB for a 400 x 250 stream whatever --chunk said (round ten)
    chunk: int = 8

    def __post_init__(self) -> None:
        if self.chunk < 1:
            raise ValueError(f"{self.name}: chunk must be >= 1, got {self.chunk}")

    def frames(self, source: WindowSource) -> Iterator[tuple[int, torch.Tensor]]:
        fn = MAP_METHODS[self.kind]
        for a in range(0, source.num_windows, self.chunk):
            b = min(a + self.chunk, source.num_windows)
            maps = fn(source.windows(a, b))
            for i in range(b - a):
                yield a + i, maps[i]


@dataclass
class SpanTFPMethod:
    """TFP over `span` steps centred on each window's centre (`tfp:N`): plain photon counting given
    as many steps as a network sees. The span is an odd number of whole windows, so it covers
    windows i - n .. i + n exactly; near the ends of the source it averages the windows there are
    (what anyone holding that stream has), so every frame has a value."""

    name: str
    span: int
    window: int = 41
    chunk: int = 8  # windows read at once (round ten: 64, whatever --chunk said)
    KEPT_WINDOWS = 64

    def __post_init__(self) -> None:
        if self.chunk < 1:
            raise ValueError(f"{self.name}: chunk must be >= 1, got {self.chunk}")
        if self.span % self.window or (self.span // self.window) % 2 == 0:
            raise ValueError(f"tfp:{self.span}: the span must be an odd number of {self.window}-step windows "
                             f"(e.g. {3 * self.window}, {5 * self.window}, {21 * self.window})")

    def frames(self, source: WindowSource) -> Iterator[tuple[int, torch.Tensor]]:
        """A running sum over the windows in reach: each window is added once as the reach passes
        its right edge and subtracted once as it leaves on the left, so time is linear in the
        stream whatever the span (restacking every window in reach for each frame took 269 s for
        tfp:328041 on 4000 windows, and held them all). A span of up to KEPT_WINDOWS windows keeps
        their counts (tfp:205: five maps), so each window is read once; a longer one reads the
        leaving window again, so memory stays at one map."""
        half, total = self.span // self.window // 2, source.num_windows
        if 2 * half + 1 > total:
            import logging
            logging.getLogger("spikesim.methods").warning(
                "%s: the span (%d steps) is longer than the %d window(s) of %d steps read: each frame averages "
                "the windows within reach, at most all %d steps", self.name, self.span, total, self.window,
                total * self.window)
        keep = 2 * half + 1 <= self.KEPT_WINDOWS  # a short span keeps its windows' counts: each read once
        kept: dict[int, torch.Tensor] = {}
        running: torch.Tensor | None = None  # spikes per pixel in windows lo..hi, exact integers
        added = 0  # windows 0 .. added - 1 are in (or were in and left) the running sum
        for i in range(total):
            hi = min(total - 1, i + half)
            while added <= hi:
                b = min(added + self.chunk, hi + 1)
                counts = source.windows(added, b).sum(dim=1, dtype=torch.int64)
                if keep:
                    kept.update({added + j: counts[j] for j in range(b - added)})
                part = counts.sum(dim=0)
                running = part if running is None else running + part
                added = b
            leaving = i - half - 1
            if leaving >= 0:
                gone = (kept.pop(leaving) if keep
                        else source.windows(leaving, leaving + 1).sum(dim=(0, 1), dtype=torch.int64))
                running = running - gone
            lo = max(0, i - half)
            yield i, running.to(torch.float32) / ((hi - lo + 1) * self.window)


def span_method_spec(body: str, window: int) -> int | None:
    """The span of a `tfp:N` spec (N steps), None for any other spec."""
    if not body.startswith("tfp:"):
        return None
    digits = body[4:]
    if not (digits.isascii() and digits.isdigit()):  # int() also takes "1_23" and other scripts' digits
        raise ValueError(f"method {body!r}: tfp:N takes a number of steps in digits 0-9, e.g. tfp:{3 * window}")
    span = int(digits)
    if span < 1:
        raise ValueError(f"method {body!r}: the span must be a positive number of steps")
    return span


@dataclass
class ModelMethod:
    """A trained network (any config), run over the stream in pieces of its training horizon
    (model.streaming.horizon_reconstruct) or, with horizon "all", by exact chunked streaming: a
    checkpoint file, or shipped weights by name (`pretrained`, model/pretrained.py)."""

    name: str
    checkpoint: Path | None
    chunk: int = 8
    device: str = "cpu"
    pretrained: str | None = None
    #: windows the recurrence runs over at once (model.streaming.horizon_reconstruct): "trained" (the
    #: network's training sequences' K, the default), a number, or "all" (exact one-shot streaming
    #: over the whole stream, `chunk` windows in memory). A published network ignores it.
    horizon: int | str = "trained"
    #: frames taken from each piece; None = default_horizon_stride(horizon)
    horizon_stride: int | None = None

    def __post_init__(self) -> None:
        check_horizon(self.horizon, self.horizon_stride)
        if self.pretrained is not None:
            from .pretrained import load_pretrained
            self.model, self.experiment = load_pretrained(self.pretrained, self.device)
        else:
            self.model, self.experiment = model_from_checkpoint(self.checkpoint, self.device)
            for_inference(self.model, self.experiment)
        self.window = self.experiment.model.window
        #: the resolved horizon in windows, None for one-shot streaming
        self.horizon_windows: int | None = None
        if isinstance(self.model, ReconNet) and self.horizon != "all":
            self.horizon_windows = self.experiment.train.num_windows if self.horizon == "trained" else int(self.horizon)
            if self.horizon_stride is None:
                self.horizon_stride = default_horizon_stride(self.horizon_windows)
            elif self.horizon_stride > self.horizon_windows:
                raise ValueError(f"{self.name}: horizon stride {self.horizon_stride} is more than its horizon of "
                                 f"{self.horizon_windows} windows")

    @property
    def span(self) -> int:
        """Steps the network saw per training sample (K windows): the span of the fair TFP."""
        return self.experiment.train.num_windows * self.window

    def frames(self, source: WindowSource) -> Iterator[tuple[int, torch.Tensor]]:
        if self.horizon_windows is None:
            yield from stream_reconstruct(self.model, source, self.chunk, self.device)
        else:
            yield from horizon_reconstruct(self.model, source, self.horizon_windows, self.horizon_stride, self.device)


def inference_record(methods: "list[Method] | tuple[Method, ...]") -> dict[str, str]:
    """How each network among `methods` ran over the streams (its horizon), for a results table:
    a table made with the default reads otherwise like one made with `--horizon all`."""
    out = {}
    for m in methods:
        net = getattr(m, "inner", m)  # a flip self-ensemble runs its network four times alike
        if isinstance(net, ModelMethod) and isinstance(net.model, ReconNet):
            out[m.name] = ("one pass over the whole stream (horizon all)" if net.horizon_windows is None else
                           f"pieces of {net.horizon_windows} windows, {net.horizon_stride} frame(s) from each")
    return out


#: What a network's `horizon` takes besides a number of windows.
HORIZON_NAMES = ("trained", "all")


def check_horizon(horizon: int | str, stride: int | None = None) -> None:
    """Refuse a horizon that is not "trained", "all" or a whole number >= 1, and a stride < 1."""
    number = isinstance(horizon, int) and not isinstance(horizon, bool)
    if not (horizon in HORIZON_NAMES or (number and horizon >= 1)):
        raise ValueError(f"horizon {horizon!r}: expected a number of windows >= 1, 'trained' (the network's "
                         "training sequences) or 'all' (the whole stream at once)")
    if stride is not None and (isinstance(stride, bool) or not isinstance(stride, int) or stride < 1):
        raise ValueError(f"horizon stride {stride!r}: expected a whole number of frames per piece >= 1")
    if stride is not None and horizon == "all":
        raise ValueError("a horizon stride applies to pieces; horizon 'all' runs the whole stream at once")


#: The spatial flips of the self-ensemble (dims of an (..., H, W) tensor): each is its own inverse.
FLIPS: tuple[tuple[int, ...], ...] = ((), (-1,), (-2,), (-2, -1))
#: The spec prefix of a network's flip self-ensemble ("flips:lrrep", "mine=flips:runs/mine/best.pt").
FLIPS_PREFIX = "flips:"


@dataclass
class _FlippedSource:
    """A window source seen through one spatial flip."""

    source: WindowSource
    dims: tuple[int, ...]

    def __post_init__(self) -> None:
        self.num_windows, self.window, self.first_step = self.source.num_windows, self.source.window, self.source.first_step

    def windows(self, start: int, stop: int) -> torch.Tensor:
        w = self.source.windows(start, stop)
        return w.flip(self.dims) if self.dims else w


@dataclass
class FlipEnsembleMethod:
    """A network's geometric self-ensemble: the stream reconstructed as it is and under each flip
    of FLIPS, each frame flipped back and the four averaged (Lim et al. 2017, EDSR's "+"; BasicSR's
    self-ensemble testing). A mirrored scene is as likely as the scene, so the four frames are four
    estimates whose independent errors the mean shrinks; it costs four passes of inference."""

    name: str
    inner: ModelMethod

    def __post_init__(self) -> None:
        self.window = self.inner.window
        self.experiment = self.inner.experiment

    @property
    def span(self) -> int:
        return self.inner.span

    def frames(self, source: WindowSource) -> Iterator[tuple[int, torch.Tensor]]:
        passes = [self.inner.frames(_FlippedSource(source, dims)) for dims in FLIPS]
        for parts in zip(*passes):
            index = parts[0][0]
            total = torch.zeros_like(parts[0][1])
            for (i, frame), dims in zip(parts, FLIPS):
                assert i == index
                total += frame.flip(dims) if dims else frame
            yield index, total / len(FLIPS)


#: The shipped network's name in every command (`--method lrrep`, `--methods lrrep`).
PRETRAINED_METHOD = "lrrep"


def pretrained_label(name: str) -> str:
    """The table label of shipped weights: LR-Rep for the shipped network, LR-Rep (suffix) for
    earlier ones kept for comparison (lrrep_v1 -> LR-Rep v1)."""
    return "LR-Rep" if name == PRETRAINED_METHOD else "LR-Rep " + name.removeprefix(PRETRAINED_METHOD + "_")


#: The published networks this project builds but ships no weights of (a name -> their CPU config).
UNSHIPPED_NETWORKS = {"s2i": "cpu_s2i", "spk2imgnet": "cpu_s2i", "wgse": "cpu_wgse", "rsir": "cpu_rsir",
                      "ssml": "cpu_ssml"}


def method_from_spec(spec: str, window: int = 41, chunk: int = 8, device: str = "cpu",
                     horizon: int | str = "trained", horizon_stride: int | None = None) -> Method:
    """"tfp", "tfi", "stp", "snm" (the traditional STP and SNM), "black", "mean", "tfp:N" (TFP over
    N steps), "lrrep" (the shipped weights; any
    name of model.pretrained.PRETRAINED, e.g. the earlier lrrep_v1) or
    a checkpoint path; "flips:NETWORK" is that network's flip self-ensemble (FlipEnsembleMethod);
    "label=..." names the method in tables. `horizon` and `horizon_stride` say how a network runs
    over a long stream (ModelMethod); the other methods do not depend on them."""
    check_horizon(horizon, horizon_stride)
    # a checkpoint path may hold "=" (runs/lr=3e-4/best.pt): an existing file is a path, not label=spec
    label, eq, body = spec.partition("=") if "=" in spec and not Path(spec).is_file() else ("", "", spec)
    if eq and not label.strip():  # a blank label named the method "" in every table (round twenty)
        raise ValueError(f"method {spec!r}: the label before '=' is blank; give one (mine={body}) or none ({body})")
    if body.startswith(FLIPS_PREFIX) and not Path(body).is_file():
        inner = method_from_spec(body.removeprefix(FLIPS_PREFIX), window, chunk, device, horizon, horizon_stride)
        if not isinstance(inner, ModelMethod):
            raise ValueError(f"method {spec!r}: a flip self-ensemble is of a network (shipped weights or a "
                             f"checkpoint); {inner.name} gives the same frame under every flip")
        return FlipEnsembleMethod(label or f"{inner.name}+flips", inner)
    if body in MAP_METHODS:
        return MapMethod(label or (body.upper() if body in ("tfp", "tfi") else body), body, window, chunk)
    if body in CLASSIC_METHODS:
        return classic_method(body, label, window, chunk, device)
    span = span_method_spec(body, window)
    if span is not None:
        return SpanTFPMethod(label or f"TFP-{span}", span, window, chunk)
    from .pretrained import PRETRAINED
    if body in PRETRAINED:
        return ModelMethod(label or pretrained_label(body), None, chunk, device, pretrained=body, horizon=horizon,
                           horizon_stride=horizon_stride)
    path = Path(body.removeprefix("ckpt:"))
    if not path.is_file() and body.lower() in UNSHIPPED_NETWORKS:
        config = UNSHIPPED_NETWORKS[body.lower()]
        raise ValueError(f"method {spec!r}: no weights of {body} ship with this project; train them "
                         f"(spikesim train --config {config} --data RLLR --out runs/{body.lower()}, or take a run of "
                         f"`compare --study table1`) and name the checkpoint: {body.upper()}=runs/{body.lower()}/last.pt")
    if not path.is_file():
        raise ValueError(f"method {spec!r}: expected one of {', '.join([*MAP_METHODS, *CLASSIC_METHODS])}, tfp:N, "
                         f"shipped weights "
                         f"({', '.join(PRETRAINED)}) or an existing checkpoint file")
    return ModelMethod(label or path.parent.name or path.stem, path, chunk, device, horizon=horizon,
                       horizon_stride=horizon_stride)

"""Golden statistics of the realistic preset: a regression guard for the simulator.

A fixed scene (four bands of constant light, from darkness to bright) is simulated with the
realistic camera and a fixed seed, and a few statistics are measured per band, each with its
standard error from batch means over pixel blocks. The stored file is rewritten only by
`spikesim golden --write`; tests compare a fresh run against it within 5 combined standard
errors, on every backend.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from spikesim.camera import SpikeCamera
from spikesim.patterns import constant_frames
from spikesim.simulate import Simulator
from spikesim.stats import firing_rate, inter_spike_intervals, window_counts

GOLDEN_PATH = Path(__file__).resolve().parents[1] / "tests" / "data" / "golden_realistic.json"
LEVELS_Y = (0.0, 0.003, 0.03, 0.3)
HEIGHT, WIDTH = 32, 64
WINDOW = 41
NUM_STEPS = 100 * WINDOW
SEED = 0
BLOCKS = 16


def golden_camera() -> SpikeCamera:
    return SpikeCamera.realistic(height=HEIGHT, width=WIDTH)


def golden_frame() -> np.ndarray:
    band = WIDTH // len(LEVELS_Y)
    frame = np.zeros((HEIGHT, WIDTH), np.float32)
    for i, y in enumerate(LEVELS_Y):
        frame[:, i * band:(i + 1) * band] = y
    return frame


def _per_pixel_stats(stream) -> dict[str, np.ndarray]:
    rate = firing_rate(stream).ravel()
    counts = window_counts(stream, WINDOW).reshape(-1, HEIGHT * WIDTH).astype(np.float64)
    mean = counts.mean(axis=0)
    fano = np.where(mean > 0, counts.var(axis=0, ddof=1) / np.maximum(mean, 1e-12), np.nan)
    dark41 = (counts == 0).mean(axis=0)
    return {"rate_per_step": rate, "fano_41": fano, "dark_fraction_41": dark41}


def measure(backend: str = "numpy") -> dict[str, Any]:
    sim = Simulator(golden_camera(), backend=backend, seed=SEED)
    stream = sim.run(constant_frames(golden_frame(), NUM_STEPS, HEIGHT, WIDTH))
    per_pixel = _per_pixel_stats(stream)
    band = WIDTH // len(LEVELS_Y)
    cols = np.tile(np.arange(WIDTH), HEIGHT)
    out: dict[str, Any] = {}
    for i, y in enumerate(LEVELS_Y):
        sel = (cols // band) == i
        entry: dict[str, Any] = {}
        for name, values in per_pixel.items():
            v = values[sel]
            blocks = np.array_split(v, BLOCKS)
            means = np.array([np.nanmean(b) if np.isfinite(b).any() else np.nan for b in blocks])
            if np.isnan(means).all():
                continue
            entry[name] = {"value": float(np.nanmean(v)),
                           "se": float(np.nanstd(means, ddof=1) / np.sqrt(np.isfinite(means).sum()))}
        # fixed-pattern spread of the rate (coefficient of variation across the band's pixels)
        r = per_pixel["rate_per_step"][sel]
        if r.mean() > 0:
            cv_blocks = np.array([b.std() / b.mean() for b in np.array_split(r, BLOCKS) if b.mean() > 0])
            entry["rate_cv"] = {"value": float(r.std() / r.mean()),
                                "se": float(cv_blocks.std(ddof=1) / np.sqrt(cv_blocks.size))}
        out[f"y={y:g}"] = entry
    isi = inter_spike_intervals(stream)
    out["all"] = {"num_isi": int(isi.size)}
    return {"config": {"camera": golden_camera().to_dict(), "levels_y": LEVELS_Y, "num_steps": NUM_STEPS,
                       "seed": SEED, "window": WINDOW, "blocks": BLOCKS, "backend": backend},
            "stats": out}


def compare(measured: dict[str, Any], golden: dict[str, Any], n_sigma: float = 5.0) -> list[str]:
    """The statistics that moved by more than n_sigma combined standard errors."""
    problems = []
    for level, entry in golden["stats"].items():
        for name, g in entry.items():
            if not isinstance(g, dict):
                continue
            m = measured["stats"].get(level, {}).get(name)
            if m is None:
                problems.append(f"{level} {name}: missing from the measurement")
                continue
            tol = n_sigma * float(np.hypot(g["se"], m["se"]))
            # A floor for statistics with (almost) no spread, e.g. an exactly repeatable rate.
            tol = max(tol, 1e-9 + 1e-6 * abs(g["value"]))
            if abs(m["value"] - g["value"]) > tol:
                problems.append(f"{level} {name}: {m['value']:.6g} vs golden {g['value']:.6g} "
                                f"(tolerance {tol:.3g} = {n_sigma:g} standard errors)")
    return problems


def load_golden(path: Path | None = None) -> dict[str, Any]:
    """The stored golden statistics (default GOLDEN_PATH), checked enough that `compare` cannot
    trip over a damaged file; errors name the file."""
    path = GOLDEN_PATH if path is None else Path(path)
    if not path.exists():
        raise FileNotFoundError(f"golden statistics {path} missing; create them with `spikesim golden --write`")
    try:
        data = json.loads(path.read_text())
    except ValueError as exc:
        raise ValueError(f"golden statistics {path}: not valid JSON ({exc}); "
                         "regenerate them with `spikesim golden --write`") from exc
    problem = _layout_problem(data)
    if problem:
        raise ValueError(f"golden statistics {path}: {problem}; regenerate them with `spikesim golden --write`")
    return data


def _layout_problem(data: Any) -> str | None:
    """What is wrong with the layout `measure` writes ({"stats": {level: {name: {"value", "se"}}}}), if anything."""
    stats = data.get("stats") if isinstance(data, dict) else None
    if not isinstance(stats, dict):
        return "no 'stats' object"
    for level, entry in stats.items():
        if not isinstance(entry, dict):
            return f"stats[{level!r}] is not an object"
        for name, g in entry.items():
            if isinstance(g, dict) and not all(isinstance(g.get(k), (int, float)) for k in ("value", "se")):
                return f"stats[{level!r}][{name!r}] lacks a numeric 'value' and 'se'"
    return None


def run(args: argparse.Namespace) -> int:
    golden = None if args.write else load_golden()  # a missing or damaged file fails before the measurement
    measured = measure(args.backend)
    if args.write:
        GOLDEN_PATH.parent.mkdir(parents=True, exist_ok=True)
        tmp = GOLDEN_PATH.with_suffix(".part")
        tmp.write_text(json.dumps(measured, indent=2) + "\n")
        tmp.replace(GOLDEN_PATH)
        print(f"wrote {GOLDEN_PATH}")
        return 0
    problems = compare(measured, golden)
    for p in problems:
        print(p)
    print("golden statistics: " + ("OK" if not problems else f"{len(problems)} statistic(s) moved"))
    return 1 if problems else 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("golden", help="check (or, with --write, regenerate) the simulator's golden statistics")
    p.add_argument("--write", action="store_true", help="overwrite the stored golden file with a new measurement")
    p.add_argument("--backend", default="numpy", choices=["numpy", "llvm", "cuda"])
    p.set_defaults(func=run)


__all__ = ["measure", "compare", "load_golden", "GOLDEN_PATH", "add_parser"]

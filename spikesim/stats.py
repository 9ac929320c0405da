"""Statistics of a spike stream, for regression tests of the simulator and for `inspect`.

All work chunk by chunk on the packed stream, so long streams need not be unpacked whole.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from .stream import SpikeStream, unpack_frames


def firing_rate(stream: SpikeStream) -> np.ndarray:
    """Spikes per step per pixel, float64 (H, W)."""
    if stream.num_steps == 0:
        return np.zeros((stream.height, stream.width))
    return stream.counts() / stream.num_steps


def dark_count_rate_hz(stream: SpikeStream, readout_period_s: float, mask: np.ndarray | None = None) -> float:
    """Mean firing rate in spikes/s over the pixels in `mask` (all by default): with no light,
    the dark-count rate."""
    rate = firing_rate(stream)
    sel = rate if mask is None else rate[mask]
    return float(sel.mean() / readout_period_s) if sel.size else 0.0


def dark_pixel_fraction(stream: SpikeStream, window: int | None = None) -> float:
    """Share of pixels without a spike: over the whole stream, or averaged over consecutive
    windows of `window` steps (e.g. 41, the reconstruction window)."""
    if window is None:
        return float((stream.counts() == 0).mean())
    n = stream.num_steps // window
    if n == 0:
        raise ValueError(f"stream of {stream.num_steps} steps is shorter than one window of {window}")
    return float(np.mean([(stream.counts(i * window, (i + 1) * window) == 0).mean() for i in range(n)]))


def window_counts(stream: SpikeStream, window: int) -> np.ndarray:
    """Spike counts per pixel in consecutive windows, int64 (n_windows, H, W)."""
    n = stream.num_steps // window
    if n == 0:
        raise ValueError(f"stream of {stream.num_steps} steps is shorter than one window of {window}")
    return np.stack([stream.counts(i * window, (i + 1) * window) for i in range(n)])


def fano_factor(stream: SpikeStream, window: int) -> float:
    """Mean over pixels of var/mean of the window counts (pixels that fired at all)."""
    c = window_counts(stream, window).astype(np.float64)
    mean = c.mean(axis=0)
    var = c.var(axis=0, ddof=1) if c.shape[0] > 1 else np.zeros_like(mean)
    ok = mean > 0
    return float((var[ok] / mean[ok]).mean()) if ok.any() else float("nan")


def fixed_pattern_spread(stream: SpikeStream) -> float:
    """Coefficient of variation of the firing rate across pixels (for uniform light: the
    fixed-pattern noise)."""
    rate = firing_rate(stream)
    m = rate.mean()
    return float(rate.std() / m) if m > 0 else float("nan")


def inter_spike_intervals(stream: SpikeStream, chunk: int = 2048, max_intervals: int | None = None) -> np.ndarray:
    """All inter-spike intervals in steps, pooled over pixels (int64)."""
    h, w = stream.height, stream.width
    last = np.full(h * w, -1, dtype=np.int64)
    out = []
    total = 0
    for a in range(0, stream.num_steps, chunk):
        bits = unpack_frames(stream.packed[a:a + chunk], h, w).reshape(-1, h * w)
        t, p = np.nonzero(bits)
        t = t.astype(np.int64) + a
        order = np.lexsort((t, p))
        t, p = t[order], p[order]
        prev = np.empty_like(t)
        if t.size:
            prev[1:] = t[:-1]
            first = np.ones(t.size, dtype=bool)
            first[1:] = p[1:] != p[:-1]
            prev[first] = last[p[first]]
            valid = prev >= 0
            isi = t[valid] - prev[valid]
            out.append(isi)
            total += isi.size
            # the last spike of each pixel in this chunk
            lastmask = np.ones(t.size, dtype=bool)
            lastmask[:-1] = p[:-1] != p[1:]
            last[p[lastmask]] = t[lastmask]
        if max_intervals is not None and total >= max_intervals:
            break
    return np.concatenate(out) if out else np.zeros(0, dtype=np.int64)


def isi_histogram(stream: SpikeStream, max_isi: int = 1000) -> np.ndarray:
    """Counts of ISIs 0..max_isi steps; the last bin collects everything longer."""
    isi = inter_spike_intervals(stream)
    return np.bincount(np.minimum(isi, max_isi), minlength=max_isi + 1)


def summary(stream: SpikeStream, readout_period_s: float = 25e-6, window: int = 41) -> dict[str, Any]:
    """The summary of a stream in memory (`spikesim inspect` computes the same keys chunk by chunk
    from a file: pipelines.inspect_cmd.summarize)."""
    rate = firing_rate(stream)
    isi = inter_spike_intervals(stream, max_intervals=5_000_000)
    out: dict[str, Any] = {
        "num_steps": stream.num_steps, "height": stream.height, "width": stream.width,
        "duration_s": stream.num_steps * readout_period_s,
        "spikes": int(round(rate.sum() * stream.num_steps)),
        "mean_rate_per_step": float(rate.mean()),
        "mean_rate_hz": float(rate.mean() / readout_period_s),
        "rate_percentiles_per_step": {p: float(np.percentile(rate, p)) for p in (1, 50, 99)},
        "dark_pixel_fraction": float((rate == 0).mean()),
    }
    if stream.num_steps >= window:
        out[f"dark_pixel_fraction_{window}_step_window"] = dark_pixel_fraction(stream, window)
    if isi.size:
        out["isi_steps"] = {"count": int(isi.size), "mean": float(isi.mean()), "min": int(isi.min()),
                            "median": float(np.median(isi)), "p99": float(np.percentile(isi, 99)),
                            "max": int(isi.max())}
    else:
        out["isi_steps"] = {"count": 0}
    return out


__all__ = ["firing_rate", "dark_count_rate_hz", "dark_pixel_fraction", "window_counts", "fano_factor",
           "fixed_pattern_spread", "inter_spike_intervals", "isi_histogram", "summary"]

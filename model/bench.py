"""Measurements for docs/model.md: parameter count, inference time per frame, training throughput.

    python -m model.bench --config full --height 250 --width 400 --windows 7 --threads 2
    python -m model.bench --config tiny --train-steps 6 --thread-sweep 1,2 --load 1   # train's default threads

Inference is timed on a synthetic low-light stream (Bernoulli spikes at rate 0.05, seeded), after
one warm-up pass (oneDNN builds its kernels per shape on the first call). Times are wall clock on
whatever else the machine is doing: say so beside the numbers.
"""
from __future__ import annotations

import argparse
import json
import os
import time

import torch

from .arch import build_model, count_parameters
from .config import load_config
from .losses import build_loss
from .streaming import TensorWindows, default_horizon_stride, horizon_reconstruct, reconstruct_windows


def synthetic_windows(windows: int, window: int, height: int, width: int, rate: float, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(windows, window, height, width, generator=g) < rate


@torch.no_grad()
def time_inference(config: str, height: int, width: int, windows: int, chunk: int | None, seed: int = 0,
                   repeats: int = 1, horizon: int | None = None, stride: int | None = None) -> dict:
    """Seconds per frame of one-shot streaming (`chunk` windows at a time), or with `horizon` of
    horizon inference (pieces of `horizon` windows, `stride` frames from each)."""
    exp = load_config(config)
    torch.manual_seed(seed)
    model = build_model(exp.model).eval()
    spikes = synthetic_windows(windows, exp.model.window, height, width, 0.05, seed)
    reconstruct_windows(model, spikes[: min(2, windows)], chunk=None)  # warm-up
    if horizon is not None:
        stride = stride or default_horizon_stride(horizon)
        run = lambda: [y for _, y in horizon_reconstruct(model, TensorWindows(spikes), horizon, stride)]  # noqa: E731
    else:
        run = lambda: reconstruct_windows(model, spikes, chunk=chunk)  # noqa: E731
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        run()
        best = min(best, time.perf_counter() - t0)
    return {"config": config, "parameters": count_parameters(model), "height": height, "width": width,
            "windows": windows, "chunk": chunk, "horizon": horizon, "horizon_stride": stride,
            "threads": torch.get_num_threads(), "seconds_total": best, "seconds_per_frame": best / windows}


def time_training(config: str, steps: int, seed: int = 0, precision: str = "fp32", channels_last: bool = False) -> dict:
    """Samples per second of forward + backward + Adam at the config's crop, batch and K, in fp32
    or under bf16 autocast, with the weights in the default or the channels-last memory format."""
    from .precision import autocast

    exp = load_config(config)
    tc = exp.train
    torch.manual_seed(seed)
    model = build_model(exp.model)
    if channels_last:
        model = model.to(memory_format=torch.channels_last)
    opt = torch.optim.Adam(model.parameters(), lr=tc.lr, betas=tuple(tc.betas))
    loss_fn = build_loss(tc.loss)
    g = torch.Generator().manual_seed(seed)
    spikes = torch.rand(tc.batch_size, tc.num_windows, exp.model.window, tc.crop, tc.crop, generator=g) < 0.05
    gt = torch.rand(tc.batch_size, tc.num_windows, tc.crop, tc.crop, generator=g) * 0.1

    def step() -> None:
        with autocast(precision, torch.device("cpu")):
            pred = model(spikes)
        loss = loss_fn(pred.float(), gt)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    step()  # warm-up
    t0 = time.perf_counter()
    for _ in range(steps):
        step()
    dt = time.perf_counter() - t0
    return {"config": config, "precision": precision, "channels_last": channels_last,
            "batch_size": tc.batch_size, "num_windows": tc.num_windows, "crop": tc.crop,
            "threads": torch.get_num_threads(), "steps": steps, "seconds_per_step": dt / steps,
            "samples_per_s": steps * tc.batch_size / dt}


def _busy(stop) -> None:  # one core's worth of load, the way another job on the machine would be
    while not stop.is_set():
        sum(range(10_000))


def thread_sweep(config: str, steps: int, threads: list[int], load: int, rounds: int = 2) -> list[dict]:
    """Training samples/s at each thread count, interleaved over `rounds` (the machine drifts), while
    `load` busy processes run beside it: `train`'s default thread count comes from this
    (docs/performance.md, "Threads"). OpenMP threads spin-wait at each barrier, so a thread that
    shares its core with another job stalls all of them; one thread does not wait on anyone."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    workers = [ctx.Process(target=_busy, args=(stop,), daemon=True) for _ in range(load)]
    for w in workers:
        w.start()
    rates: dict[int, list[float]] = {n: [] for n in threads}
    try:
        for _ in range(rounds):
            for n in threads:
                torch.set_num_threads(n)
                rates[n].append(time_training(config, steps)["samples_per_s"])
    finally:
        stop.set()
        for w in workers:
            w.join(timeout=5)
    base = max(rates[threads[0]])
    return [{"config": config, "threads": n, "load_processes": load, "samples_per_s": max(r),
             "ratio_to_first": max(r) / base} for n, r in rates.items()]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", default="full")
    p.add_argument("--height", type=int, default=250)
    p.add_argument("--width", type=int, default=400)
    p.add_argument("--windows", type=int, default=7)
    p.add_argument("--chunk", type=int, default=None, help="streaming chunk (default: one-shot)")
    p.add_argument("--horizon", type=int, default=None, help="time horizon inference with pieces of this many windows")
    p.add_argument("--horizon-stride", type=int, default=None, help="frames per piece (default: the horizon less 2)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--repeats", type=int, default=1)
    p.add_argument("--train-steps", type=int, default=0, help="also time this many training steps")
    p.add_argument("--train-variants", action="store_true",
                   help="time training in fp32 and bf16, each with and without channels_last, interleaved "
                        "(ratios from one run: the machine drifts)")
    p.add_argument("--thread-sweep", help="comma-separated thread counts: time training at each (with --train-steps)")
    p.add_argument("--load", type=int, default=0, help="busy processes beside a --thread-sweep (simulated load)")
    a = p.parse_args(argv)
    if a.thread_sweep:
        from spikesim.machine import cpu_model

        print(json.dumps({"cpu": cpu_model(), "cores": os.cpu_count()}))
        for row in thread_sweep(a.config, a.train_steps or 6, [int(t) for t in a.thread_sweep.split(",")], a.load):
            print(json.dumps(row))
        return 0
    torch.set_num_threads(a.threads)
    print(json.dumps(time_inference(a.config, a.height, a.width, a.windows, a.chunk, repeats=a.repeats,
                                         horizon=a.horizon, stride=a.horizon_stride)))
    if a.train_steps and a.train_variants:
        variants = [(p, cl) for p in ("fp32", "bf16") for cl in (False, True)]
        rates: dict[tuple[str, bool], list[float]] = {v: [] for v in variants}
        for _ in range(2):  # interleaved, twice, so a drift of the machine hits every variant alike
            for p_, cl in variants:
                rates[(p_, cl)].append(time_training(a.config, a.train_steps, precision=p_, channels_last=cl)["samples_per_s"])
        base = max(rates[("fp32", False)])
        for (p_, cl), r in rates.items():
            print(json.dumps({"config": a.config, "precision": p_, "channels_last": cl, "samples_per_s": max(r),
                              "ratio_to_fp32": max(r) / base, "threads": torch.get_num_threads()}))
    elif a.train_steps:
        print(json.dumps(time_training(a.config, a.train_steps)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

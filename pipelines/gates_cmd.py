"""`spikesim gates`: where a refining network trusts the window average, scene by scene.

A network with a refining head (model.output "refine", as the shipped `lrrep`) makes each frame as
Y = g * C + (1 - g) * N: N its own frame, C the classic estimate (TFP and TFI of the window, blended
by m; with a span gate s, TFP first blended with the span's mean rate), g the gate between them.
Per scene this prints the mean gates, the share of pixels whose frame is mostly C (g > 0.5), the
mean of N against the ground truth's, and the PSNR (plain and aligned, as `evaluate` gives them)
of Y, of N alone and of C alone, on the frames `evaluate` scores. With -o it writes gates.csv and
gates.md there, and with --maps two pictures per scene of its middle frame: SCENE_panel.png
(ground truth | Y | N | C, one display scale: the ground truth's) and SCENE_gate.png (g, white =
the classic estimate).

    spikesim gates --data data/test_nat6 --method lrrep
    spikesim gates --data data/test_nat6 --method runs/mine/best.pt --scenes rllr_0003 -o out/gates --maps
"""
from __future__ import annotations

import argparse
import csv
import io
import sys
from pathlib import Path

from pipelines.argtypes import add_threads_argument, positive_int

GATE_TABLES = ("gates.csv", "gates.md")


def map_files(scene: str) -> tuple[str, str]:
    """The --maps pictures of a scene ("root:scene" of several roots keeps both names)."""
    stem = scene.replace(":", "_").replace("/", "_")
    return f"{stem}_panel.png", f"{stem}_gate.png"


def cmd_gates(args: argparse.Namespace) -> int:
    import numpy as np

    from model.data import open_scenes
    from model.gates import GATE_FIELDS, gate_scene, gates_markdown, refining_network
    from model.methods import method_from_spec
    from model.threads import set_cpu_threads
    from spikesim.dataset import select_scenes
    from model.training import resolve_device

    if args.maps and args.out is None:
        raise ValueError("--maps writes pictures into the -o folder: give -o")
    device = str(resolve_device(args.device))
    set_cpu_threads(args.threads)
    method = method_from_spec(args.method, chunk=args.chunk, device=device)
    refining_network(method)  # a window average or a direct network is refused before any scene is read
    scenes = select_scenes(open_scenes(args.data), args.scenes, args.data)
    out = None if args.out is None else Path(args.out)
    names = [*GATE_TABLES, *(f for s in scenes for f in map_files(s.name))] if args.maps else list(GATE_TABLES)
    if out is not None:
        from spikesim.dataset import check_outside_datasets
        from spikesim.outputs import check_results_owned
        check_outside_datasets(out, [args.data])
        if out.exists():
            check_results_owned(out, names, "gates")
    rows, maps = [], []
    from tqdm import tqdm
    for scene in tqdm(scenes, desc="gates", unit="scene", disable=args.quiet, file=sys.stderr):
        row, m = gate_scene(scene, method)
        rows.append(row)
        maps.append(m)
    table = gates_markdown(rows)
    print(f"Gates of {method.name} on {args.data}:\n\n{table}")
    if out is None:
        return 0
    from spikesim.imageio import write_png
    from spikesim.outputs import atomic_write_text, output_folder, results_writing, writable
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=GATE_FIELDS, lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow(r.as_row())
    with output_folder(out), results_writing(out, names, "gates"):
        atomic_write_text(writable(out, "gates.csv"), buf.getvalue())
        atomic_write_text(writable(out, "gates.md"), f"# Gates of {method.name} on {args.data}\n\n{table}")
        if args.maps:
            for row, m in zip(rows, maps):
                panel_name, gate_name = map_files(row.scene)
                white = float(np.percentile(m.ground_truth, 99.5))
                panel = np.concatenate([m.ground_truth, m.frame, m.net, m.classic], axis=1)
                # one scale for all four, the ground truth's 99.5th percentile as white (a black truth: y = 1)
                write_png(writable(out, panel_name), panel, scale=1.0 / white if white > 0 else 1.0)
                write_png(writable(out, gate_name), m.classic_gate, gamma=1.0, scale=1.0)
    print(f"[gates] wrote {out / 'gates.csv'} and {out / 'gates.md'}"
          + (f" and {2 * len(rows)} pictures" if args.maps else ""), file=sys.stderr)
    return 0


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register `gates` on the CLI's subparsers."""
    p = subparsers.add_parser("gates", help="where a refining network trusts the window average, per scene",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", required=True, help="dataset root (project layout)")
    p.add_argument("--method", default="lrrep",
                   help="a network with a refining head: lrrep (the shipped one), another shipped name or a "
                        "checkpoint path (default lrrep)")
    p.add_argument("--scenes", nargs="+", help="only these scenes (default: all)")
    p.add_argument("-o", "--out", help="write gates.csv and gates.md here (default: print only)")
    p.add_argument("--maps", action="store_true", help="with -o: each scene's middle frame as pictures")
    p.add_argument("--chunk", type=positive_int, default=8, help="windows held in memory at once (the frames do not "
                                                                 "depend on it)")
    p.add_argument("--device", default="auto", help="auto (CUDA when present), cpu, cuda, cuda:N or mps")
    add_threads_argument(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_gates)
    return p

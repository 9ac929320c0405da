"""Weights that ship inside the package, loaded by name (`--method lrrep`, `load_pretrained()`).

A shipped file is weights-only: the network's config, its parameters and where they came from, no
optimiser state. The registry below holds each file's sha256 and its weights' fingerprint (the
model card in docs/model.md prints the same); a file that does not match is refused, so a damaged
or swapped file never reconstructs anything.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import torch

from .checkpoint import (FORMAT_VERSION, atomic_torch_save, for_inference, load_checkpoint, model_from_checkpoint,
                         state_fingerprint)
from .config import ExperimentConfig

WEIGHTS_DIR = resources.files(__package__) / "weights"


@dataclass(frozen=True)
class PretrainedWeights:
    """One shipped weights file and what it must hash to."""

    name: str
    file: str
    file_sha256: str
    weights_sha256: str
    summary: str


#: The shipped weights by name (docs/model.md, "Model card": how they were made and scored).
PRETRAINED: dict[str, PretrainedWeights] = {
    "lrrep": PretrainedWeights(
        name="lrrep", file="lrrep_budget.pt",
        file_sha256="4ea02f4126c023c87332fcab7491328c54b63c26ac5956a5d1678a94809c25c0",
        weights_sha256="fd2e3d5aa793aedc12bcf1eb68db5ca8ff677de0fbf7331bde1e51fb29db3217",
        summary="the budget run: the paper's (E) with the refining output, trained from a random draw (seed 21) in "
                "11,000 steps on two CPU cores (config lrrep_span_shot, lr 1e-3 cosine, scripts/budget_run.sh with "
                "DATA_VARIANT=procedural) on 8 rendered natural scenes, 240 video-like photo scenes and 40 procedural "
                "scenes; data and training 1.8 CPU-hours on a 2-core AMD EPYC (Zen 5)"),
    "lrrep_v6": PretrainedWeights(
        name="lrrep_v6", file="lrrep_gpu.pt",
        file_sha256="459f2f2dfd8cbc221d878acb3d8189c8e0744dce0c9c47a8c39df10291dbbccf",
        weights_sha256="3474b268ca1a688d5ce85090ecc542d0356f57b66ff3b3e9ada51b38f9250ccb",
        summary="the seventh stage, kept for comparison (shipped as lrrep until the budget run): the sixth stage's "
                "recipe at GPU scale, lrrep_v5 fine-tuned 2.3 minutes on a lent H200 (the GPU campaign's stage recipe: "
                "config lrrep_span, batch 32 of 48 x 48, lr 2e-4 cosine, 1,290 steps) on the sixth stage's eight sets "
                "made on that GPU with the same commands and seeds"),
    "lrrep_v5": PretrainedWeights(
        name="lrrep_v5", file="lrrep_still.pt",
        file_sha256="9e2c1d04937fbbc59d5f6fc5eb587531ad3e7bc4a46d042133e08068fa078322",
        weights_sha256="dfedb2777cc123bd50de06f3e74e4366bbbc18fe658eaa4d1d097d5a1f896887",
        summary="the sixth stage, kept for comparison: lrrep_v4's network (the span's average at the refining "
                "head) fine-tuned 103 minutes on two CPU cores (config lrrep_span, lr 1e-4 cosine) on 8 rendered natural "
                "scenes and 240 video-like photo scenes, 144 of them with a still camera (dark, at video brightness and "
                "brighter)"),
    "lrrep_v4": PretrainedWeights(
        name="lrrep_v4", file="lrrep_span.pt",
        file_sha256="44a0e5d62cf77e70c58d75ed44485adfe8189ac7d3996b3029abbf5af6150383",
        weights_sha256="2e2b2e4f3ec5afd559fa360491dc039b2a93e9c385b87bc6ab6f2a34f19af085",
        summary="the fifth stage, kept for comparison: (E) at 16 features and 2 blocks, K = 5, GISI as 1/interval, "
                "with the refining output and the span's average at its head (gates to the window's TFP and TFI and to TFP over the 5 windows around it): "
                "lrrep_v3 fine-tuned about 85 minutes on two CPU cores (config lrrep_span) on 8 rendered natural scenes "
                "and 192 video-like photo scenes, half at video brightness, half with a still camera"),
    "lrrep_v3": PretrainedWeights(
        name="lrrep_v3", file="lrrep_refine.pt",
        file_sha256="8c3011faec4df249a4c20ce37499d59c1a5707d166d5f17e759cefaa0aaa87fc",
        weights_sha256="f8e9151278a59bd1c12234127a82262e80a9661a41cea62017e7e07dbcb6cd7e",
        summary="the fourth stage, kept for comparison: (E) at 16 features and 2 blocks, K = 5, GISI as 1/interval, "
                "with the refining output (per-pixel gates to the window's TFP and TFI): lrrep_v2 fine-tuned 47 "
                "minutes on two CPU cores (config lrrep_refine) on 8 rendered natural scenes and 96 video-like photo "
                "scenes, half of them at video brightness"),
    "lrrep_v2": PretrainedWeights(
        name="lrrep_v2", file="lrrep_nat.pt",
        file_sha256="430d80fbe024e2b348d91c8e5df3fb9532ae459cdcae04c23c332eadd95a6aa8",
        weights_sha256="0950df04a4c3d972144e512d57d476d08e271daf710598ba9e532dcb7c091611",
        summary="the third stage, kept for comparison: (E) at 16 features and 2 blocks, K = 5, GISI as 1/interval: "
                "lrrep_v1 fine-tuned 35 minutes on two CPU cores (config lrrep_finetune) on 48 natural-content RLLR "
                "scenes (dead leaves, photographs, camera motion, 0.1-1000 lx, pixel scales 1, 1/2, 1/4, the measured "
                "camera)"),
    "lrrep_v1": PretrainedWeights(
        name="lrrep_v1", file="lrrep_cpu.pt",
        file_sha256="64bab0f2cb1f231a443c14b72c5c2e52becf495af46104931378368f5b22e936",
        weights_sha256="8bde3d69a67b2890166667d665a0a4690bf9b8753290a4d17e1d77dc75de58de",
        summary="the first shipped network, kept for comparison: (E) at 16 features and 2 blocks, K = 5, trained 33 "
                "minutes on two CPU cores (config lrrep_cpu) on 40 procedural RLLR scenes at 400 x 250, then "
                "fine-tuned 50 minutes from those weights (--init, lr 3e-4)"),
}


def pretrained_path(name: str = "lrrep") -> Path:
    """The file of shipped weights `name`, checked against the registry's sha256."""
    if name not in PRETRAINED:
        known = ", ".join(sorted(PRETRAINED)) or "none"
        raise ValueError(f"no shipped weights called {name!r} (shipped: {known})")
    entry = PRETRAINED[name]
    path = Path(str(WEIGHTS_DIR / entry.file))
    if not path.is_file():
        raise FileNotFoundError(f"shipped weights {name!r}: {path} is missing from the installed package "
                                "(reinstall spikesim)")
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    if digest != entry.file_sha256:
        raise ValueError(f"shipped weights {name!r}: {path} has sha256 {digest[:16]}..., the model card says "
                         f"{entry.file_sha256[:16]}...: the file is damaged or was replaced (reinstall spikesim)")
    return path


def load_pretrained(name: str = "lrrep", device: str | torch.device = "cpu"
                    ) -> tuple[torch.nn.Module, ExperimentConfig]:
    """The shipped network `name` in eval mode, with its config, on `device`.

    GISI is clipped at the training horizon, as for any trained checkpoint (checkpoint.for_inference)."""
    path = pretrained_path(name)
    from .training import resolve_device
    device = resolve_device(device, "device")  # "gpu", 0, "cpu:1" blamed the weights or raised torch's own error
    model, experiment = model_from_checkpoint(path, device)
    fingerprint = state_fingerprint(model.state_dict())
    if fingerprint != PRETRAINED[name].weights_sha256:
        raise ValueError(f"shipped weights {name!r}: weights fingerprint {fingerprint[:16]}... differs from the "
                         f"model card's {PRETRAINED[name].weights_sha256[:16]}...")
    return for_inference(model, experiment), experiment


def export_weights(checkpoint: str | Path, out: str | Path, provenance: dict[str, Any] | None = None) -> dict[str, str]:
    """Write a training checkpoint's network as a weights-only file (config, fp32 parameters,
    provenance; no optimiser): what ships. Returns the file's sha256 and the weights' fingerprint,
    the two values a registry entry holds."""
    state = load_checkpoint(checkpoint)
    weights = {k: v.float() if v.is_floating_point() else v for k, v in state["model_state"].items()}
    doc = {"format_version": FORMAT_VERSION, "experiment": state["experiment"], "model_state": weights,
           "optimizer_state": None, "step": state.get("step", 0), "epoch": state.get("epoch", 0),
           "weights_sha256": state_fingerprint(weights),
           "extra": {"provenance": provenance or {}, "source_checkpoint_step": int(state.get("step", 0))}}
    atomic_torch_save(doc, out)
    return {"file_sha256": hashlib.sha256(Path(out).read_bytes()).hexdigest(),
            "weights_sha256": doc["weights_sha256"]}


__all__ = ["PRETRAINED", "PretrainedWeights", "load_pretrained", "pretrained_path", "export_weights", "WEIGHTS_DIR"]

"""Dataset generation as a library: plan scene jobs (LLR, RLLR, a user's own scene) and run them,
resumably and in parallel, exactly as `spikesim generate` does.

>>> from spikesim.generation import PRESETS, plan_llr, generate
>>> jobs = plan_llr(PRESETS["small"], scenes=["ball"])      # doctest: +SKIP
>>> report = generate(jobs, "out/llr_small")                # doctest: +SKIP

`plan` (presets, jobs, seeds), `run` (resumable generation and the manifest), `job` (one scene
folder), `pool` (local processes or Ray), `lock` (one run per output folder).
"""
from __future__ import annotations

from spikesim.generation.job import run_job
from spikesim.generation.plan import (PRESETS, WINDOW, Preset, SceneJob, bundled_scene, llr_windows, plan_llr,
                                      plan_rllr, plan_user, scene_seed)
from spikesim.generation.run import generate, job_status, percent, saturation_summary, scene_state

__all__ = ["PRESETS", "WINDOW", "Preset", "SceneJob", "bundled_scene", "llr_windows", "plan_llr", "plan_rllr",
           "plan_user", "scene_seed", "generate", "job_status", "scene_state", "saturation_summary", "percent",
           "run_job"]

"""The GPU campaign: every GPU measurement and a training run, in one 9-minute call of a lent GPU
machine by default (part `one`; parts `1` and `2` split it over two calls for a longer lease)
(docs/gpu_campaign.md; `spikesim gpu-campaign`, `scripts/gpu_campaign.sh`).

One job per module, each importing only those above it in this list, so data flows one way:

- `options`: the stages, parts and profiles, and the `Options` of one invocation;
- `records`: `StageRecord`, what summary.json says of a stage;
- `outputs`: the files handed back (at most 8) and the checks that they come back;
- `stages`: the running `Campaign` (commands under a time box) and the stages themselves;
- `runner`: the run: the stages in order, each in its box, and summary.json, logs.txt, report.md;
- `cmd`: the command line (`python -m pipelines.gpu_campaign.cmd`), which this package does not
  import, so that running it as `-m` finds it unloaded.
"""
from __future__ import annotations

from pipelines.gpu_campaign.options import (DATA_STAGES, DEFAULT_PART, INJECTIONS, OPTIONAL, PART_DEADLINE_S, PARTS,
                                            PROFILES, RECIPE_CALL, ROOT, STAGE_NAMES, TABLE1_CALL, TRADEOFF_CALL, Options,
                                            Profile)
from pipelines.gpu_campaign.outputs import join_weight_parts
from pipelines.gpu_campaign.records import STATUSES, StageRecord
from pipelines.gpu_campaign.runner import SCHEMA_VERSION, earlier_outputs, run_campaign, summary_of

__all__ = ["Options", "Profile", "PROFILES", "PARTS", "DEFAULT_PART", "OPTIONAL", "TABLE1_CALL", "TRADEOFF_CALL", "PART_DEADLINE_S", "STAGE_NAMES",
           "STATUSES", "DATA_STAGES", "INJECTIONS", "RECIPE_CALL", "ROOT", "StageRecord", "run_campaign", "summary_of", "earlier_outputs", "join_weight_parts", "SCHEMA_VERSION"]

"""What summary.json says of each stage of a GPU campaign: its status, seconds, figures and log.

The stages (stages.py) fill a record while they run and the run (runner.py) writes them; neither
is imported here.
"""
from __future__ import annotations

import dataclasses
from typing import Any

STATUSES = ("ok", "failed", "skipped", "timeout")
#: The schema of summary.json and of the work folder's state.json.
SCHEMA_VERSION = 1


@dataclasses.dataclass
class StageRecord:
    """What summary.json says of a stage."""

    name: str
    status: str = "skipped"
    seconds: float = 0.0
    figures: dict[str, Any] = dataclasses.field(default_factory=dict)
    log: str | None = None
    note: str | None = None
    commands: list[str] = dataclasses.field(default_factory=list)
    returncode: int | None = None
    time_box_s: float | None = None
    started: str | None = None
    part: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "StageRecord":
        return cls(**{f.name: data[f.name] for f in dataclasses.fields(cls) if f.name in data})


__all__ = ["STATUSES", "SCHEMA_VERSION", "StageRecord"]

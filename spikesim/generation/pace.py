"""A line in the log as each scene of a generation finishes: its time, the estimate's for it, and
the time left at the pace measured so far.

Progress bars are drawn only on a terminal (spikesim.progress); a run logged to a file, as a
paper-size generation usually is (hours), would otherwise say nothing between its estimate and
its end. The lines also check the estimate scene by scene, where it can be wrong (the paper
RLLR's was 24 % over until a moving scene's sub-steps were counted once; docs/performance.md 4a).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping


@dataclass
class Pace:
    """What has finished so far. `estimated_s` holds the estimate's seconds for each job on one of
    `workers` workers (Estimate.job_seconds; empty where no estimate was made)."""

    total: int
    workers: int = 1
    estimated_s: Mapping[str, float] = field(default_factory=dict)
    done: int = 0
    measured_s: float = 0.0
    """Seconds of the finished scenes that the estimate has figures for."""
    predicted_s: float = 0.0
    """The estimate's seconds for those scenes."""
    _finished: set[str] = field(default_factory=set)

    def __post_init__(self) -> None:
        if self.total < 0 or self.workers < 1:
            raise ValueError(f"Pace: total {self.total} must be >= 0 and workers {self.workers} >= 1")

    def finished(self, result: Mapping[str, Any]) -> str:
        """Record one finished scene (run_job's result: name, seconds) and say where the run stands."""
        name, seconds = str(result["name"]), float(result["seconds"])
        self.done += 1
        self._finished.add(name)
        line = f"{name} done in {seconds:.1f} s"
        guess = self.estimated_s.get(name)
        if guess is not None:
            self.measured_s += seconds
            self.predicted_s += guess
            line += f" (estimated {guess:.1f} s)"
        line += f"; {self.done} of {self.total} scene(s) done"
        left = self.left_s()
        if left is not None and self.done < self.total:
            when = f"{left / 60:.1f} min" if left >= 60 else f"{left:.0f} s"
            line += (f"; about {when} left on {self.workers} worker(s) at the pace so far "
                     f"(the estimate's remaining work x {self.measured_s / self.predicted_s:.2f})")
        return line

    def left_s(self) -> float | None:
        """The estimate's seconds for the scenes not finished, scaled by measured over estimated for
        those that are, shared over the workers (over fewer when fewer scenes are left); None
        before a scene with an estimate finishes. The scenes under way count whole."""
        if self.predicted_s <= 0:
            return None
        rest = [s for name, s in self.estimated_s.items() if name not in self._finished]
        return sum(rest) * (self.measured_s / self.predicted_s) / max(1, min(self.workers, len(rest)))


__all__ = ["Pace"]

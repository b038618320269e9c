"""One submission's check as data: its rows, the whole filter's figures, the seed, what went wrong."""

from __future__ import annotations

from dataclasses import dataclass, field

from mazelab.exercise.rows import Row
from mazelab.exercise.whole import ScenarioFigures


@dataclass
class Report:
    """One submission's check: its rows (the parts, then the whole filter), the whole filter's figures
    per scenario, the seed of its inputs, what went wrong beyond the rows, the time it took, and
    whether it ran unsandboxed."""

    filter_name: str
    seed: int
    rows: list[Row] = field(default_factory=list)
    figures: list[ScenarioFigures] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    seconds: float = 0.0
    output: str = ""
    note: str = ""  # where the child was not sandboxed: the one line saying its verdict cannot be trusted

    @property
    def passed(self) -> bool:
        """Every row passed (exit code 0)."""
        return bool(self.rows) and all(row.passed for row in self.rows)

    def row(self, part: str) -> Row:
        """The row of one part (or "whole filter")."""
        return next(row for row in self.rows if row.part == part)


__all__ = ["Report"]

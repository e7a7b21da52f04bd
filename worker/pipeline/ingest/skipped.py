"""Records a reader could not use: skip them, count them, and refuse only when too few remain.

Real logs carry the odd unreadable value (a firmware glitch, a truncated write, a
`N/A`); refusing a whole flight for one such record throws away minutes of good
telemetry. A reader raises `RecordError` for one record, collects it in `Skipped`
and goes on; `Skipped.check` then refuses the file only when what is left is too little
to trust: fewer than `MIN_USABLE` records (or none of a one-record file), or fewer than
`MIN_USABLE_FRACTION` of them. Then so many errors mean the reader misunderstands
the file, and the message shows how much was readable and the first reasons.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from worker.pipeline.errors import InputError

MIN_USABLE = 2
MIN_USABLE_FRACTION = 0.5
_SHOWN = 5  # reasons quoted in a message; the rest are counted


class RecordError(InputError):
    """One record (SRT block, CSV row) of a log cannot be read; the file may still be."""

    def __init__(self, name: str, line: int, reason: str) -> None:
        super().__init__(f"{name}, line {line}: {reason}")
        self.line = line
        self.reason = reason


@dataclass
class Skipped:
    """The records of one file that were skipped, with their line and reason."""

    name: str
    unit: str  # "blocks" or "rows", for messages
    items: list[tuple[int, str]] = field(default_factory=list)

    def add(self, error: RecordError) -> None:
        self.items.append((error.line, error.reason))

    def __len__(self) -> int:
        return len(self.items)

    def _reasons(self) -> str:
        shown = "; ".join(f"line {line}: {reason}" for line, reason in self.items[:_SHOWN])
        more = len(self.items) - _SHOWN
        return shown + (f"; and {more} more" if more > 0 else "")

    def check(self, total: int) -> list[str]:
        """Raise when too little of `total` records is usable, else the warnings to report."""
        if not self.items:
            return []
        usable = total - len(self.items)
        if usable < min(MIN_USABLE, total) or usable < MIN_USABLE_FRACTION * total:
            raise InputError(
                f"{self.name}: only {usable} of {total} {self.unit} readable; {self._reasons()}"
            )
        return [
            f"{self.name}: {len(self.items)} of {total} {self.unit} unreadable and skipped "
            f"({self._reasons()})"
        ]


def off_earth(lat: float | None, lon: float | None) -> bool:
    """A latitude/longitude no position on Earth has (a garbled number)."""
    return (lat is not None and abs(lat) > 90) or (lon is not None and abs(lon) > 180)

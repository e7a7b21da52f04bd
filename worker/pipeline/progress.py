"""Progress reporting shared by all stages."""

from collections.abc import Callable

ProgressFn = Callable[[float], None]
"""Called with the fraction of the stage done, from 0.0 to 1.0."""


def no_progress(_fraction: float) -> None:
    """Default progress sink for callers that do not track progress."""

"""The registry of detection methods: the one list the CLI, the API, jobs and the page use.

Adding a method is one module that declares a `DetectionMethod` (see methods/threshold.py)
plus one registration: a line in `_BUILT_IN` below, or, for a method kept outside the
project, its module named in the setting `SLIDEWATCH_DETECTION_METHOD_MODULES` (it calls
`register_method` when imported; `load_method_modules` imports it in every process).
"""

from __future__ import annotations

import importlib
from collections.abc import Iterable
from enum import StrEnum

from worker.pipeline.comparison_layout import DetectionMethod
from worker.pipeline.errors import InputError
from worker.pipeline.methods import cnn, scored, threshold

__all__ = [
    "DetectionMethod",
    "MethodName",
    "default_method",
    "detection_method",
    "detection_methods",
    "load_method_modules",
    "method_names",
    "register_method",
]


class MethodName(StrEnum):
    """The methods shipped with slidewatch (registered ones may add more)."""

    threshold = "threshold"
    scored = "scored"
    cnn = "cnn"


_BUILT_IN = (threshold.METHOD, scored.METHOD, cnn.METHOD)
_REGISTRY: dict[str, DetectionMethod] = {}


def register_method(method: DetectionMethod) -> DetectionMethod:
    """Make a method available everywhere; registering the same declaration again is a no-op."""
    known = _REGISTRY.get(method.name)
    if known is not None and known != method:
        raise ValueError(f"a different detection method is already registered as {method.name!r}")
    stage_names = {m.stage.name for m in _REGISTRY.values() if m.name != method.name}
    if method.stage.name in stage_names | {"align", "coregister", "difference"}:
        raise ValueError(f"detection stage name {method.stage.name!r} is taken")
    _REGISTRY[method.name] = method
    return method


def unregister_method(name: str) -> None:
    """Forget a registered method (a built-in one cannot be removed)."""
    if name in {m.name for m in _BUILT_IN}:
        raise ValueError(f"{name!r} is a built-in detection method")
    _REGISTRY.pop(name, None)


def load_method_modules(modules: Iterable[str]) -> None:
    """Import the modules that register methods kept outside the project (a setting)."""
    for module in modules:
        try:
            importlib.import_module(module)
        except ImportError as exc:
            raise ValueError(
                f"detection method module {module!r} cannot be imported: {exc}"
            ) from exc


def detection_methods() -> tuple[DetectionMethod, ...]:
    return tuple(_REGISTRY.values())


def method_names() -> tuple[str, ...]:
    return tuple(_REGISTRY)


def detection_method(name: str) -> DetectionMethod:
    try:
        return _REGISTRY[name]
    except KeyError:
        raise InputError(
            f"unknown detection method {name!r}; available: {', '.join(_REGISTRY)}"
        ) from None


def default_method() -> str:
    """The one default of the product: the CLI, the API and the page all use it.

    `threshold`, the LoD method with its per-pixel error model, because the default must
    never be worse than the simple baseline (one NMAD for the raster) on any benchmark
    set, and on the detection benchmark of 2026-11-25 (docs/significance.md) it was not:
    same or higher slide recall on every generator, fewer false alarms on most. `scored`
    cut false alarms further but missed two slides that the LoD method found, so it is
    chosen by name until it recovers them. ComparisonOptions itself also defaults to
    it, so stored parameters keep their meaning.
    """
    return MethodName.threshold.value


for _method in _BUILT_IN:
    register_method(_method)

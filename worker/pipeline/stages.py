"""A pipeline is data: an ordered list of stage specs, run by one runner.

A `StageSpec` says everything the rest of the platform needs to know about a stage: its
name, the files of earlier stages it reads, the files it writes (and which of them become
products, with their kind, media type and raster role), its share of the progress bar, a
one-line help and the library function that runs it. The library's runner (`Pipeline.run`,
`Pipeline.run_stage`), the CLI (`--from-stage`), the job layer (one Celery task per stage,
products registered from `outputs`), the API and the page's stage help are all derived from
the specs, so a stage is declared in one place.

A stage function takes the pipeline's context (its inputs, work folder and options: one
dataclass per pipeline) and a progress callback, and returns a result with `to_dict()`
(a dataclass) or a JSON-friendly dict; the runner hands back the dict.
"""

from __future__ import annotations

import dataclasses
import time
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, Protocol, Self, TypeVar

from worker.pipeline.cog import COG_MEDIA_TYPE, RasterRole
from worker.pipeline.errors import InputError, PipelineError
from worker.pipeline.progress import ProgressFn, no_progress

GEOJSON = "application/geo+json"
GEOTIFF = "image/tiff"
__all__ = [
    "COG_MEDIA_TYPE",
    "GEOJSON",
    "GEOTIFF",
    "Output",
    "Pipeline",
    "PipelineRun",
    "StageResult",
    "StageSpec",
]


class StageResult:
    """Base of a stage's typed result (a dataclass): to JSON with `to_dict`, and back with
    `from_dict` from what a job stored or a stage wrote (keys it does not know are left
    out, so a result written by a newer version still reads)."""

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)  # type: ignore[call-overload]

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Self:
        hints = typing.get_type_hints(cls)
        names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
        return cls(
            **{key: _json_value(hints[key], value) for key, value in data.items() if key in names}
        )


def _json_value(hint: Any, value: Any) -> Any:
    """JSON has lists only: a list read back for a tuple field becomes the tuple again."""
    kinds = (hint, *typing.get_args(hint))
    if isinstance(value, list) and any(typing.get_origin(k) is tuple for k in kinds):
        return tuple(value)
    return value


class StageContext(Protocol):
    """What every pipeline's context has: the folder its stages read and write."""

    @property
    def work_dir(self) -> Path: ...


ContextT = TypeVar("ContextT", bound=StageContext)


@dataclass(frozen=True)
class Output:
    """A file a stage writes into the work folder.

    `product` names the product kind it becomes (None: a working file only). A raster with
    a `raster_role` is served as a Cloud-Optimized GeoTIFF made from it, whose overviews are
    resampled by that role; one already written as a COG says so in its media type. An
    `optional` output may be missing after its stage ran (the stage's result says why),
    and is then no product.
    """

    file: str
    product: str | None = None
    media_type: str = "application/octet-stream"
    raster_role: RasterRole | None = None
    optional: bool = False


@dataclass(frozen=True)
class StageSpec(Generic[ContextT]):
    name: str
    run: Callable[[ContextT, ProgressFn], Any]
    help: str  # one line for people: what the stage does (page, CLI, API)
    inputs: tuple[str, ...] = ()  # files of earlier stages, relative to the work folder
    outputs: tuple[Output, ...] = ()
    weight: float = 1.0  # relative share of the pipeline's progress bar (measured times)

    def products(self) -> tuple[Output, ...]:
        return tuple(output for output in self.outputs if output.product)


@dataclass(frozen=True)
class Pipeline(Generic[ContextT]):
    """An ordered list of stages over one work folder."""

    name: str
    stages: tuple[StageSpec[ContextT], ...]
    _by_name: dict[str, StageSpec[ContextT]] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        names = [stage.name for stage in self.stages]
        if len(set(names)) != len(names):
            raise ValueError(f"the {self.name} pipeline names a stage twice: {names}")
        object.__setattr__(self, "_by_name", {stage.name: stage for stage in self.stages})

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(stage.name for stage in self.stages)

    def stage(self, name: str) -> StageSpec[ContextT]:
        try:
            return self._by_name[name]
        except KeyError:
            raise InputError(
                f"{name!r} is not a stage of the {self.name} pipeline; its stages are "
                f"{', '.join(self.names)}"
            ) from None

    def weights(self) -> dict[str, float]:
        """Each stage's share of the whole progress bar (they sum to 1)."""
        total = sum(stage.weight for stage in self.stages) or 1.0
        return {stage.name: stage.weight / total for stage in self.stages}

    def following(self, name: str) -> tuple[StageSpec[ContextT], ...]:
        """The stage `name` and every stage after it."""
        start = self.names.index(self.stage(name).name)
        return self.stages[start:]

    def run_stage(
        self, name: str, context: ContextT, progress: ProgressFn = no_progress
    ) -> dict[str, Any]:
        """Run one stage on what earlier stages left in the work folder; its result dict."""
        spec = self.stage(name)
        work = Path(context.work_dir)
        work.mkdir(parents=True, exist_ok=True)
        missing = [file for file in spec.inputs if not (work / file).exists()]
        if missing:
            raise PipelineError(
                f"stage {name!r} needs {', '.join(missing)} in {work}; run the earlier stages first"
            )
        result = spec.run(context, progress)
        return result.to_dict() if hasattr(result, "to_dict") else dict(result)

    def run(
        self,
        context: ContextT,
        progress: ProgressFn = no_progress,
        from_stage: str | None = None,
    ) -> PipelineRun:
        """Run the stages in order (from `from_stage` on: the earlier ones must have run)."""
        start = time.perf_counter()
        weights = self.weights()
        stages = self.following(from_stage) if from_stage else self.stages
        results: dict[str, dict[str, Any]] = {}
        done = sum(weights[s.name] for s in self.stages[: len(self.stages) - len(stages)])
        for spec in stages:
            weight = weights[spec.name]

            def stage_progress(fraction: float, done: float = done, weight: float = weight) -> None:
                progress(min(1.0, done + weight * fraction))

            results[spec.name] = self.run_stage(spec.name, context, stage_progress)
            done += weight
        progress(1.0)
        return PipelineRun(results, Path(context.work_dir), time.perf_counter() - start)


@dataclass
class PipelineRun:
    """The results of the stages that ran (name -> result dict), in order."""

    results: dict[str, dict[str, Any]]
    work_dir: Path
    seconds: float

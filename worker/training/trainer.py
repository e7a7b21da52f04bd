"""One entry point for training a detection model from a dataset manifest, shared by
`slidewatch train` and the platform's training job (worker/jobs/training.py).

Model kinds: "slidenet" (ours, dense_training.py) and "patchnet-fixed" /
"patchnet-loose" (the paper's, paper_training.py). The manifest's test pair and region
are held out unless `include_test`: with a margin of a patch (42 pixels) for the patch
models and of 64 pixels for SlideNet, whose receptive field is wider than a patch.
`overrides` sets fields of the kind's training options (epochs, steps_per_epoch, ...);
an unknown field is an InputError. Seeded; resumes from the checkpoint in `out_dir`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

from worker.pipeline.errors import InputError

if TYPE_CHECKING:  # the training modules import torch: only when training
    from worker.training.training import LogFn, TrainingResult

MODEL_KINDS = ("slidenet", "patchnet-fixed", "patchnet-loose")
EXCLUSION_MARGIN_PX = {"slidenet": 64, "patchnet": 42}


def _options(cls: type, overrides: dict[str, Any], **fixed: Any) -> Any:
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(overrides) - names
    if unknown:
        raise InputError(f"unknown training options: {', '.join(sorted(unknown))}")
    values = {**overrides, **fixed}
    for f in dataclasses.fields(cls):  # JSON gives lists where the options hold tuples
        if isinstance(f.default, tuple) and isinstance(values.get(f.name), list):
            values[f.name] = tuple(values[f.name])
    return cls(**values)


def train_model(
    dataset_path: Path,
    out_dir: Path,
    model_kind: str,
    name: str | None = None,
    seed: int = 0,
    threads: int = 2,
    overrides: dict[str, Any] | None = None,
    include_test: bool = False,
    log: LogFn | None = None,
) -> TrainingResult:
    """Train a model of `model_kind` on the manifest into `out_dir`; returns the result
    (card path, card, history)."""
    from worker.training.dataset import load_manifest
    from worker.training.training import Exclusion, quiet

    log = log or quiet
    if model_kind not in MODEL_KINDS:
        raise InputError(f"unknown model kind {model_kind!r}; kinds are {', '.join(MODEL_KINDS)}")
    manifest = load_manifest(Path(dataset_path))
    family = model_kind.split("-")[0]
    exclude = None
    if manifest.test and not include_test:
        exclude = Exclusion(
            manifest.test["pair"], manifest.test["region"], EXCLUSION_MARGIN_PX[family]
        )
    name = name or model_kind
    overrides = dict(overrides or {})
    if family == "slidenet":
        from worker.training.dense_training import DenseTrainingOptions, train_slidenet

        options = _options(DenseTrainingOptions, overrides, seed=seed, num_threads=threads)
        return train_slidenet(manifest, Path(out_dir), name, options, exclude, log)
    from worker.training.paper_training import PatchTrainingOptions, train_patchnet

    mode = model_kind.split("-")[1]
    options = _options(PatchTrainingOptions, overrides, mode=mode, seed=seed, num_threads=threads)
    return train_patchnet(manifest, Path(out_dir), name, options, exclude, log)


__all__ = ["MODEL_KINDS", "train_model"]

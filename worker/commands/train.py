"""`slidewatch train`: train a landslide detection model on a dataset manifest.

    slidewatch train --dataset data/mounds/dataset.json --out models/ --model slidenet
    slidewatch train --simulate paper-mounds --data-dir data/mounds --out models/ \\
        --model patchnet-loose --max-per-class 1561
    slidewatch train --simulate training-set --data-dir data/cnn-train --out models/ \\
        --threads 1       # the shipped SlideNet's data and options

`--dataset` takes any detection dataset manifest (worker/training/dataset.py).
`--simulate` makes one: the scenario's survey videos rendered and reconstructed by
slidewatch, as the paper trained on its own DSO DSMs
(worker/training/reconstructed_data.py), or with `--dsm-source recon-noise` the quick
interim stand-in (truth DSMs degraded by worker/training/recon_noise.py, no rendering).
The test pair/region of the manifest is held out unless `--include-test`. Seeded and
resumable: run the same command again after an interruption and it continues from the
last finished epoch. Prints one JSON line: the model card's path, the model version,
the validation metrics.
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from worker.commands.options import dsm_source_option
from worker.pipeline.errors import InputError
from worker.training.trainer import MODEL_KINDS

EXIT_INPUT_ERROR = 2


@click.command("train")
@click.option(
    "--dataset",
    "dataset_path",
    type=click.Path(path_type=Path),
    default=None,
    help="Dataset manifest (JSON) of pre/post/mask GeoTIFF triples.",
)
@click.option(
    "--simulate",
    type=click.Choice(["paper-mounds", "hillslope", "training-set"]),
    default=None,
    help="Simulate this scenario and make its dataset (in --data-dir).",
)
@dsm_source_option
@click.option(
    "--data-dir", type=click.Path(path_type=Path), default=None, help="Where --simulate writes."
)
@click.option("--out", "out_dir", required=True, type=click.Path(path_type=Path))
@click.option("--model", "model_kind", type=click.Choice(MODEL_KINDS), default="slidenet")
@click.option("--name", default=None, help="Model name (default: from --model).")
@click.option("--epochs", type=int, default=None, help="Default: 100 (paper) / 40 (slidenet).")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--threads", type=int, default=2, show_default=True)
@click.option(
    "--max-per-class",
    type=int,
    default=None,
    help="Patch models: cap per class after balancing (the paper had 1561).",
)
@click.option("--include-test", is_flag=True, help="Also train on the manifest's test region.")
def train(
    dataset_path: Path | None,
    simulate: str | None,
    dsm_source: str,
    data_dir: Path | None,
    out_dir: Path,
    model_kind: str,
    name: str | None,
    epochs: int | None,
    seed: int,
    threads: int,
    max_per_class: int | None,
    include_test: bool,
) -> None:
    """Train a detection model; print the model card path and metrics as JSON."""
    from worker.training.trainer import train_model

    def log(message: str) -> None:
        click.echo(message, err=True)

    try:
        if simulate:
            from worker.training.reconstructed_data import (
                default_training_set,
                reconstructed_dataset,
                survey_simulation,
            )
            from worker.training.simdata import simulate_dataset

            folder = data_dir or out_dir / f"data-{simulate}-seed{seed}"
            if simulate == "training-set":
                dataset_path = default_training_set(folder, log=log)
            else:
                dataset_path = folder / "dataset.json"
                if dataset_path.exists():
                    pass
                elif dsm_source == "reconstruction":
                    reconstructed_dataset(folder, simulate, survey_simulation(seed), log=log)
                else:
                    simulate_dataset(folder, simulate, seed)
        if dataset_path is None:
            raise InputError("give --dataset MANIFEST or --simulate SCENARIO")
        name = name or model_kind
        overrides: dict[str, int] = {}
        if epochs:
            overrides["epochs"] = epochs
        if max_per_class is not None and model_kind != "slidenet":
            overrides["max_per_class"] = max_per_class

        result = train_model(
            dataset_path,
            out_dir / name,
            model_kind,
            name,
            seed,
            threads,
            overrides,
            include_test,
            log,
        )
    except InputError as exc:
        click.echo(f"error: {exc}", err=True)
        raise SystemExit(EXIT_INPUT_ERROR) from exc
    click.echo(
        json.dumps(
            {
                "card": str(result.card_path),
                "model": f"{result.card.name}@{result.card.version}",
                "interim_data": result.card.interim,
                "epochs": len(result.history),
                "resumed_from_epoch": result.resumed_from_epoch,
                "seconds": round(result.seconds, 1),
                "validation": result.card.metrics.get("validation"),
            }
        )
    )

"""`slidewatch calibrate`: the decision rule's min_score of a trained model, and publishing.

    slidewatch calibrate --model models/slidenet/slidenet.json \\
        --no-change data/paper-mounds-seed5-no-change/dataset.json \\
        --no-change data/hillslope-seed5-no-change/dataset.json \\
        --slides data/paper-mounds-seed0/dataset.json#step1-step3 \\
        --slides data/hillslope-seed3-random-slides/dataset.json \\
        --work-dir data/calibration [--publish slidenet-default]

Runs the cnn comparison with min_score 0 on every pair (the first pair of a dataset, or
the one after `#`) and chooses min_score (worker/training/calibration.py). Prints the
calibration as JSON; `--publish NAME` copies the model with that min_score into the
package's weights folder as NAME (the shipped default is `slidenet-default`).
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from worker.pipeline.errors import InputError

EXIT_INPUT_ERROR = 2


def _pairs(specs: tuple[str, ...]) -> dict:
    from worker.training.dataset import load_manifest, load_pair

    pairs = {}
    for spec in specs:
        path, _, pair_id = spec.partition("#")
        manifest = load_manifest(Path(path))
        pair = manifest.pair(pair_id) if pair_id else manifest.pairs[0]
        pairs[f"{manifest.name}/{pair.id}"] = load_pair(pair)
    return pairs


@click.command("calibrate")
@click.option("--model", "card", required=True, type=click.Path(path_type=Path))
@click.option("--no-change", multiple=True, required=True, help="Dataset manifest[#PAIR].")
@click.option("--slides", multiple=True, required=True, help="Dataset manifest[#PAIR].")
@click.option("--work-dir", required=True, type=click.Path(path_type=Path))
@click.option("--threads", type=int, default=2, show_default=True)
@click.option("--publish", default=None, help="Copy the calibrated model into the package.")
def calibrate(
    card: Path,
    no_change: tuple[str, ...],
    slides: tuple[str, ...],
    work_dir: Path,
    threads: int,
    publish: str | None,
) -> None:
    """Calibrate a model's min_score on no-change pairs and pairs with slides."""
    from worker.pipeline.cnn.options import PACKAGE_WEIGHTS
    from worker.pipeline.cnn.registry import publish_model
    from worker.training.calibration import calibrate_min_score

    try:
        result = calibrate_min_score(card, _pairs(no_change), _pairs(slides), work_dir, threads)
    except InputError as exc:
        click.echo(f"error: {exc}", err=True)
        raise SystemExit(EXIT_INPUT_ERROR) from exc
    report = {"min_score": result.min_score, **result.to_dict()}
    if publish:
        decision = {"min_score": result.min_score, "min_score_calibration": result.to_dict()}
        report["published"] = str(publish_model(card, PACKAGE_WEIGHTS, publish, decision=decision))
    click.echo(json.dumps(report))

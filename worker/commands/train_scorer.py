"""`slidewatch train-scorer`: fit, calibrate and card the `scored` method's scorer.

    slidewatch train-scorer --out worker/pipeline/scorer_weights/scorer-default.json \\
        --train ridge-debris --train terraced-strips --train urban-rockfall \\
        --calibrate agri-shallow --evaluate fractal-forest --evaluate mountain-deep \\
        --seeds 10 --work-dir data/scorer

Candidates come from the pair generators (worker/pairgen/): fitted on the --train
generators, Platt-calibrated and thresholded (recall first) on the --calibrate ones, and
the calibration of every generator, the --evaluate ones never seen, goes in the card
(worker/detection_bench/scorer_training.py). Pairs and comparisons are cached in
--work-dir, so a second run is quick.
"""

from __future__ import annotations

import json
from pathlib import Path

import click


@click.command("train-scorer")
@click.option("--out", type=click.Path(path_type=Path), required=True, help="Scorer JSON.")
@click.option("--train", "training", multiple=True, required=True, help="Fitting generator.")
@click.option("--calibrate", "calibration", multiple=True, required=True)
@click.option("--evaluate", "evaluation", multiple=True, help="Held-out generator (card only).")
@click.option("--seeds", type=int, default=10, show_default=True)
@click.option("--target-recall", type=float, default=0.98, show_default=True)
@click.option(
    "--work-dir", type=click.Path(path_type=Path), default=Path("data/scorer"), show_default=True
)
def train_scorer_command(
    out: Path,
    training: tuple[str, ...],
    calibration: tuple[str, ...],
    evaluation: tuple[str, ...],
    seeds: int,
    target_recall: float,
    work_dir: Path,
) -> None:
    """Fit the scorer on some generators, calibrate it on others, card it."""
    from worker.detection_bench.runner import resolve_generators
    from worker.detection_bench.scorer_training import (
        collect_candidates,
        save_scorer,
        train_scorer,
    )

    overlap = (set(training) & set(calibration)) | (
        set(evaluation) & (set(training) | set(calibration))
    )
    if overlap:
        raise click.UsageError(f"a generator is in two roles: {', '.join(sorted(overlap))}")
    try:
        generators = resolve_generators([*training, *calibration, *evaluation])
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None
    candidates = collect_candidates(work_dir, generators, range(seeds))
    scorer = train_scorer(candidates, training, calibration, target_recall)
    save_scorer(scorer, out)
    card = scorer.card
    click.echo(
        json.dumps({k: card[k] for k in ("training_candidates", "threshold_rule")}, indent=1)
    )
    click.echo(f"threshold {scorer.threshold:.3f}")
    for name, rel in card["reliability_by_generator"].items():
        click.echo(f"{name:18s} ECE {rel['ece']:.3f} over {rel['candidates']} candidates")
    click.echo(f"written to {out}")

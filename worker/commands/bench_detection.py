"""`slidewatch bench detection`: the detection benchmark (Tables 6/7 of the paper).

    slidewatch bench detection --json benchmarks/results/detection.json

A subcommand of the `bench` group (worker/commands/bench.py). The detection benchmark
simulates its data (survey videos reconstructed by slidewatch), trains the paper's two
models (cached in --work-dir, resumable), evaluates every detector on patterns A-D on
paper-mounds and the hillslope, checks no-change pairs for false alarms and measures
inference speed; it prints the tables and writes everything to --json
(worker/pipeline/cnn/benchmark.py).
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from worker.commands.options import dsm_source_option


@click.command("detection")
@click.option("--json", "json_path", type=click.Path(path_type=Path), required=True)
@click.option(
    "--work-dir",
    type=click.Path(path_type=Path),
    default=Path("data/bench-detection"),
    show_default=True,
    help="Simulated data, the paper's trained models and evaluation files (reused).",
)
@click.option("--model", default=None, help="Our best model (card path); default: shipped.")
@click.option(
    "--scenario",
    "scenarios",
    multiple=True,
    type=click.Choice(["paper-mounds", "hillslope"]),
    help="Default: both.",
)
@click.option("--paper-epochs", type=int, default=100, show_default=True)
@dsm_source_option
@click.option("--no-speed", is_flag=True, help="Skip the inference-speed measurement.")
@click.option(
    "--threads", type=int, default=2, show_default=True, help="Torch threads for the tables."
)
@click.option(
    "--speed-threads", type=int, default=2, show_default=True, help="Torch threads for speed."
)
@click.option(
    "--speed-size",
    type=int,
    default=5000,
    show_default=True,
    help="Side in pixels of the speed pair at 20 cm/pixel (5000: 1 km2); smaller is quicker.",
)
def detection(
    json_path: Path,
    work_dir: Path,
    model: str | None,
    scenarios: tuple[str, ...],
    paper_epochs: int,
    dsm_source: str,
    no_speed: bool,
    threads: int,
    speed_threads: int,
    speed_size: int,
) -> None:
    """Tables 6/7 replicated for every detector; false alarms; inference speed."""
    from worker.pipeline.cnn.benchmark import run_benchmark

    report = run_benchmark(
        work_dir,
        json_path,
        best_model=model,
        scenarios=scenarios or ("paper-mounds", "hillslope"),
        paper_epochs=paper_epochs,
        speed=not no_speed,
        threads=threads,
        speed_threads=speed_threads,
        speed_size=speed_size,
        dsm_source=dsm_source,
    )
    click.echo(report["text"])
    click.echo("")
    click.echo("no-change pairs: " + json.dumps(report["no_change"]))
    if "speed" in report:
        click.echo("speed: " + json.dumps(report["speed"]))
    click.echo(f"written to {json_path}")

"""`slidewatch bench detection`: the detection benchmarks, one suite at a time.

    slidewatch bench detection --json benchmarks/results/detection-generators.json
    slidewatch bench detection --suite paper --json benchmarks/results/detection.json

A subcommand of the `bench` group (worker/commands/bench.py).

`--suite generators` (the default) runs every detection method on generated DSM pairs
and their no-change twins (worker/pairgen/, `--seeds` per generator) and scores them per
generator: patch F1, slide recall by depth and size, false alarms, area and volume
errors, seconds and failures (worker/detection_bench/). Pairs and runs live in
--work-dir; pairs already written are reused.

`--suite paper` is the paper-protocol benchmark (Tables 6/7; about an hour): it
simulates its data (survey videos reconstructed by slidewatch), trains the paper's two
models (cached in --work-dir, resumable), evaluates every detector on patterns A-D on
paper-mounds and the hillslope, checks no-change pairs for false alarms and measures
inference speed (worker/training/benchmark.py).

Each prints its tables and writes everything to --json. Options of one suite are
refused with the other, rather than silently ignored.
"""

from __future__ import annotations

import json
from pathlib import Path

import click
from click.core import ParameterSource

from worker.commands.options import dsm_source_option

SUITES = ("generators", "paper")
DEFAULT_WORK_DIRS = {
    "generators": Path("data/bench-detection-generators"),
    "paper": Path("data/bench-detection"),
}
# Parameter names (click's) that belong to one suite only.
ONLY_FOR = {
    "paper": ("scenarios", "paper_epochs", "dsm_source", "speed_threads"),
    "generators": (
        "generator_names",
        "methods",
        "seeds",
        "first_seed",
        "held_out",
        "leave_one_out",
        "training_seeds",
        "publish_card",
    ),
}


@click.command("detection")
@click.option(
    "--suite",
    type=click.Choice(SUITES),
    default="generators",
    show_default=True,
    help="generators: every method on generated pairs; paper: the paper's Tables 6/7.",
)
@click.option("--json", "json_path", type=click.Path(path_type=Path), required=True)
@click.option(
    "--work-dir",
    type=click.Path(path_type=Path),
    default=None,
    help="Data, models and evaluation files (reused). Default: data/bench-detection "
    "(paper) or data/bench-detection-generators (generators).",
)
@click.option("--model", default=None, help="The cnn method's model (card path); default: shipped.")
@click.option(
    "--generator",
    "generator_names",
    multiple=True,
    help="generators suite: a pair generator (repeatable); default: all registered.",
)
@click.option(
    "--method",
    "methods",
    multiple=True,
    help="generators suite: a detection method (repeatable); default: every method.",
)
@click.option(
    "--seeds",
    type=click.IntRange(min=1),
    default=5,
    show_default=True,
    help="generators suite: pairs per generator, each with its twin.",
)
@click.option(
    "--first-seed",
    type=click.IntRange(min=0),
    default=1000,
    show_default=True,
    help="generators suite: seeds first-seed .. first-seed+N-1; the scorer trains on seeds "
    "from 0, so the benchmark's pairs are never its training pairs.",
)
@click.option(
    "--leave-one-out",
    "leave_one_out",
    type=click.Path(path_type=Path),
    default=None,
    help="generators suite: also score each generator with a scorer fitted and calibrated "
    "on the others only (method scored-logo), from the candidates of the training seeds "
    "cached in this folder (slidewatch train-scorer's --work-dir; made there if missing).",
)
@click.option(
    "--training-seeds",
    type=click.IntRange(min=1),
    default=12,
    show_default=True,
    help="generators suite, with --leave-one-out: seeds 0..N-1 of every generator train.",
)
@click.option(
    "--publish-card",
    type=click.Path(path_type=Path, exists=True),
    default=None,
    help="generators suite: write the per-generator figures into this scorer's card.",
)
@click.option(
    "--held-out",
    "held_out",
    multiple=True,
    help="generators suite: a generator no model was fitted to (repeatable); default: "
    "those not in worker.pipeline.scorer.TRAINING_GENERATORS (none without it).",
)
@click.option(
    "--scenario",
    "scenarios",
    multiple=True,
    type=click.Choice(["paper-mounds", "hillslope"]),
    help="paper suite; default: both.",
)
@click.option("--paper-epochs", type=int, default=100, show_default=True, help="paper suite.")
@dsm_source_option
@click.option("--no-speed", is_flag=True, help="Skip the inference-speed run.")
@click.option(
    "--threads",
    type=int,
    default=2,
    show_default=True,
    help="Torch threads of the cnn detector (paper suite: for the tables).",
)
@click.option(
    "--speed-threads",
    type=int,
    default=2,
    show_default=True,
    help="paper suite: torch threads for speed.",
)
@click.option(
    "--speed-size",
    type=int,
    default=5000,
    show_default=True,
    help="Side in pixels of the speed pair at 20 cm/pixel (5000: 1 km2); smaller is quicker.",
)
@click.pass_context
def detection(
    ctx: click.Context,
    suite: str,
    json_path: Path,
    work_dir: Path | None,
    model: str | None,
    generator_names: tuple[str, ...],
    methods: tuple[str, ...],
    seeds: int,
    first_seed: int,
    leave_one_out: Path | None,
    training_seeds: int,
    publish_card: Path | None,
    held_out: tuple[str, ...],
    scenarios: tuple[str, ...],
    paper_epochs: int,
    dsm_source: str,
    no_speed: bool,
    threads: int,
    speed_threads: int,
    speed_size: int,
) -> None:
    """Detection benchmarks: per-generator scores (default) or the paper's Tables 6/7."""
    refuse_other_suite_options(ctx, suite)
    work_dir = work_dir or DEFAULT_WORK_DIRS[suite]
    if suite == "paper":
        paper_suite(
            json_path,
            work_dir,
            model,
            scenarios,
            paper_epochs,
            dsm_source,
            no_speed,
            threads,
            speed_threads,
            speed_size,
        )
    else:
        generators_suite(
            json_path,
            work_dir,
            model,
            generator_names,
            methods,
            range(first_seed, first_seed + seeds),
            held_out,
            threads,
            None if no_speed else speed_size,
            (leave_one_out, training_seeds) if leave_one_out else None,
            publish_card,
        )


def refuse_other_suite_options(ctx: click.Context, suite: str) -> None:
    for other, names in ONLY_FOR.items():
        if other == suite:
            continue
        given = [
            p.opts[0]
            for p in ctx.command.params
            if p.name in names and ctx.get_parameter_source(p.name) is not ParameterSource.DEFAULT
        ]
        if given:
            raise click.UsageError(f"{', '.join(given)}: only with --suite {other}")


def generators_suite(
    json_path: Path,
    work_dir: Path,
    model: str | None,
    generator_names: tuple[str, ...],
    methods: tuple[str, ...],
    seeds: range,
    held_out: tuple[str, ...],
    threads: int,
    speed_size: int | None,
    leave_one_out: tuple[Path, int] | None = None,
    publish_card: Path | None = None,
) -> None:
    from worker.detection_bench import runner
    from worker.pipeline.atomic import write_text_atomic
    from worker.pipeline.comparison import ComparisonOptions
    from worker.pipeline.detection_methods import method_names

    try:
        generators = runner.resolve_generators(generator_names, work_dir)
        chosen = runner.validate_methods(methods or (*method_names(), *runner.VARIANTS))
        names = [g.name for g in generators]
        held = runner.validate_held_out(held_out, names) if held_out else None
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from None
    cnn = ComparisonOptions(method="cnn")
    cnn.detection.model = model
    cnn.detection.num_threads = threads
    report = runner.run_generator_benchmark(
        work_dir,
        generators,
        chosen,
        list(seeds),
        options_by_method={"cnn": cnn},
        log=lambda line: click.echo(line, err=True),
        held_out=runner.default_held_out(names) if held is None else held,
    )
    if leave_one_out:
        from worker.detection_bench.leave_one_out import add_leave_one_out

        add_leave_one_out(
            report,
            work_dir,
            generators,
            list(runner.available_generators(work_dir).values()),
            leave_one_out[0],
            range(leave_one_out[1]),
            log=lambda line: click.echo(line, err=True),
        )
    if speed_size:
        from worker.detection_bench.speed import detection_speed

        report["speed"] = detection_speed(work_dir, speed_size)
    write_text_atomic(json_path, runner.report_json(report))
    if publish_card:
        import sys

        from worker.detection_bench.scorer_training import publish_benchmark

        clean = json.loads(runner.report_json(report))
        publish_benchmark(clean, publish_card, "slidewatch " + " ".join(sys.argv[1:]))
    click.echo(runner.format_tables(report))
    if speed_size:
        speed = report["speed"]
        click.echo(
            f"speed at 20 cm, {speed['area_km2']:.2f} km2: scored "
            f"{speed['scored_km2_per_min']} km2/min (difference {speed['difference_s']} s + "
            f"score {speed['score_s']} s), threshold {speed['threshold_km2_per_min']} km2/min"
        )
    click.echo(f"written to {json_path}")


def paper_suite(
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
    from worker.training.benchmark import run_benchmark

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

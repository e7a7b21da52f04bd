"""Leave one generator out: the `scored` method on each generator with a scorer that
never saw it.

For each benchmarked generator g, a scorer is fitted on three of the other pair
generators and calibrated (Platt scaling, recall-first threshold) on the remaining two
(`folds`; the survey simulator's pairs, never in the pool, get a scorer of the whole
pool), from the candidates of training seeds (cached by scorer_training), then
the `score` stage runs with it on g's benchmark pairs and twins, reusing their
comparison's first stages. The runs enter the report as the method "scored-logo", so
every figure of that row is on a generator its scorer was not fitted or calibrated to.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from worker.detection_bench.aggregate import aggregate_report
from worker.detection_bench.detections import read_detections
from worker.detection_bench.metrics import score_pair
from worker.detection_bench.runner import KINDS, PairGenerator, describe_run, failed_run
from worker.detection_bench.scorer_training import (
    collect_candidates,
    save_scorer,
    train_scorer,
)
from worker.pairgen.pair import PAIR_CRS
from worker.pipeline import comparison
from worker.pipeline.difference import ERROR_MODEL_FILE, LOD_FILE

METHOD = "scored-logo"
SHARED_FILES = (
    comparison.PRE_ALIGNED,
    comparison.POST_COREGISTERED,
    comparison.DH,
    comparison.SIGNIFICANCE,
    LOD_FILE,
    ERROR_MODEL_FILE,
)


def folds(names: Sequence[str]) -> dict[str, tuple[list[str], list[str]]]:
    """g -> (training, calibration): the others in a fixed cyclic order after g, the
    first two calibrating and the rest fitting."""
    ordered = sorted(names)
    out = {}
    for i, name in enumerate(ordered):
        others = ordered[i + 1 :] + ordered[:i]
        out[name] = (others[2:], others[:2])
    return out


def add_leave_one_out(
    report: dict[str, Any],
    work_dir: Path,
    generators: Sequence[PairGenerator],
    all_generators: Sequence[PairGenerator],
    training_dir: Path,
    training_seeds: Sequence[int],
    log: Callable[[str], Any] = print,
) -> None:
    """Add the "scored-logo" runs and aggregates to a generator benchmark's report."""
    pool = [g for g in all_generators if g.name in _pool_names()]
    candidates = collect_candidates(training_dir, pool, training_seeds, log=lambda _: None)
    plan = folds([g.name for g in pool])
    runs: list[dict[str, Any]] = []
    for generator in generators:
        training, calibration = plan.get(generator.name) or _outside_pool(plan)
        scorer = train_scorer(
            candidates, training, calibration, name=f"scorer-without-{generator.name}"
        )
        scorer_path = Path(work_dir) / "leave-one-out" / f"{generator.name}.json"
        save_scorer(scorer, scorer_path)
        options = comparison.ComparisonOptions(method="scored")
        options.detection.scorer = str(scorer_path)
        for seed in report["seeds"]:
            for kind in KINDS:
                pair = generator.make(seed, no_change=kind == "twin")
                base = _first_stages_dir(Path(work_dir), generator.name, seed, kind)
                run_dir = Path(work_dir) / "runs" / generator.name / f"seed{seed}" / kind / METHOD
                run = {"generator": generator.name, "seed": seed, "kind": kind, "method": METHOD}
                run |= _score_run(pair, base, run_dir, options)
                runs.append(run)
                log(describe_run(run))
    report["runs"] = [r for r in report["runs"] if r["method"] != METHOD] + runs
    report["methods"] = [m for m in report["methods"] if m != METHOD] + [METHOD]
    report["leave_one_out"] = {
        g.name: dict(
            zip(("training", "calibration"), plan.get(g.name) or _outside_pool(plan), strict=True)
        )
        for g in generators
    }
    report["aggregates"] = aggregate_report(
        report["runs"], report["methods"], report["generators"], report["held_out"]
    )


def _pool_names() -> set[str]:
    """Generators whose candidates train the folds: the pair generators (worker/pairgen/);
    the survey simulator's pairs are only ever scored."""
    from worker.pairgen import GENERATORS

    return set(GENERATORS)


def _outside_pool(plan: dict[str, tuple[list[str], list[str]]]) -> tuple[list[str], list[str]]:
    """A generator outside the pool is scored by a scorer of the whole pool."""
    names = sorted(plan)
    return names[2:], names[:2]


def _first_stages_dir(work_dir: Path, generator: str, seed: int, kind: str) -> Path:
    for method in ("scored", "threshold"):
        folder = work_dir / "runs" / generator / f"seed{seed}" / kind / method
        if all((folder / name).exists() for name in SHARED_FILES):
            return folder
    raise FileNotFoundError(
        f"no comparison of {generator} seed {seed} {kind} to reuse: benchmark the "
        "scored or threshold method with it"
    )


def _score_run(
    pair: Any, base: Path, run_dir: Path, options: comparison.ComparisonOptions
) -> dict[str, Any]:
    shutil.rmtree(run_dir, ignore_errors=True)
    run_dir.mkdir(parents=True)
    for name in SHARED_FILES:
        os.link(base / name, run_dir / name)
    try:
        result = comparison.run_stage("score", run_dir, run_dir, run_dir, options)
        detections = read_detections(
            run_dir / comparison.DETECTIONS, pair.transform, pair.shape, PAIR_CRS
        )
    except Exception as exc:  # a failure is a result of the benchmark, not its end
        return failed_run(pair, exc)
    return {
        "ok": True,
        "error": None,
        "seconds": result["seconds"],
        "comparison": {"detections": result["detections"], "model": result["model"]},
        **score_pair(pair, detections),
    }

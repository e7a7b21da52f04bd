"""Plain-text tables of a generator benchmark report: one per method, a row per generator,
then the all-generators and held-out rows. Held-out generators are marked with `*`."""

from __future__ import annotations

from typing import Any

from worker.detection_bench.metrics import DEPTH_CLASSES

COLUMNS = (
    f"{'generator':<19}| {'F1 med':>6} {'p10':>5} {'worst':>5} "
    f"| {'R>3LoD&>10x10px':>15} | {'R <1':>5} {'1-3':>5} {'>=3LoD':>6} "
    f"| {'FA m2/km2 med':>13} {'worst':>7} | {'|area e|':>8} {'|vol e|':>8} "
    f"| {'s/pair':>6} | {'fail':>4}"
)


def number(value: float | None, digits: int = 2, width: int = 5) -> str:
    return f"{'-':>{width}}" if value is None else f"{value:>{width}.{digits}f}"


def row(label: str, agg: dict[str, Any]) -> str:
    deep = agg["recall_deep_large"]
    deep_text = f"{deep['found']}/{deep['total']}"
    if deep["recall"] is not None:
        deep_text += f" {deep['recall']:.2f}"
    depth = " ".join(
        number(agg["recall_by_depth_lod"][c]["recall"], width=6 if c == ">=3" else 5)
        for c in DEPTH_CLASSES
    )
    fa = agg["twin_false_alarm_m2_per_km2"]
    return (
        f"{label:<19}| {number(agg['f1_median'], 3, 6)} {number(agg['f1_p10'])} "
        f"{number(agg['f1_worst'])} | {deep_text:>15} | {depth} "
        f"| {number(fa['median'], 0, 13)} {number(fa['worst'], 0, 7)} "
        f"| {number(agg['area_error_abs_median'], 2, 8)} "
        f"{number(agg['volume_error_abs_median'], 2, 8)} "
        f"| {number(agg['seconds_per_pair']['median'], 1, 6)} | {agg['failures']:>4}"
    )


def format_tables(report: dict[str, Any]) -> str:
    """A table per method (see the module doc)."""
    held_out = set(report.get("held_out") or [])
    blocks = []
    for method, aggregates in report["aggregates"].items():
        lines = [f"method {method}  (* held-out generator)", COLUMNS, "-" * len(COLUMNS)]
        for name, agg in aggregates["by_generator"].items():
            lines.append(row(name + ("*" if name in held_out else ""), agg))
        lines.append("-" * len(COLUMNS))
        lines.append(row("all generators", aggregates["all"]))
        if aggregates.get("held_out"):
            lines.append(row("held-out*", aggregates["held_out"]))
        blocks.append("\n".join(lines))
    legend = (
        "F1: patch F1 over pairs (p10: reached by 90 % of pairs); R: slide recall "
        "(found: >= 25 % covered), by depth in LoD = 1.96 x error NMAD; FA: false-alarm "
        "m2 per km2 on no-change twins; |area e|, |vol e|: median relative errors of "
        "found slides; s/pair: median seconds per comparison; fail: failed runs."
    )
    missing = [
        f"no pair: {u['generator']} seed {u['seed']} {u['kind']}: {u['reason']}"
        for u in report.get("unavailable_pairs") or []
    ]
    return "\n\n".join([*blocks, legend, *(["\n".join(missing)] if missing else [])])


__all__ = ["format_tables"]

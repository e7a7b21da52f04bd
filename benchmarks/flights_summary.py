"""Summary of the many-flight benchmark (benchmarks/flights.py) per scenario x GNSS mode.

For every figure: median, p90 and worst over the flights that succeeded (worst is the
largest error, or the smallest completeness / speed); success over all flights (a flight
fails when the pipeline stops or its DSM cannot be co-registered onto the truth). Each
target is judged on the statistic it names:

- success >= 95 % (every group);
- RTK logs: DSM NMAD as georeferenced <= 2 px median and <= 3 px p90;
- after shift + tilt co-registration: DSM NMAD <= 2 px p90 (either GNSS);
- hillslope: trajectory RMSE (after the best similarity: the reconstruction's shape;
  as georeferenced it is the GNSS error's) <= 0.5 m, judged on p90;
- sfm / slam wall time >= 10 median (the `--sfm-every` subset);
- real-time factor (video seconds per second of the reconstruct stage) >= 1 median.

`by_condition` groups the same flights by the harder condition they drew (cross
pattern, low sun, texture-poor field, rolling shutter, or none: flights.CONDITIONS),
over every scenario and GNSS mode, with the same figures (no targets: the targets are
per scenario and GNSS mode).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Figure:
    """One per-flight figure: where it is in a flight record, and which way is worse."""

    name: str
    get: Callable[[dict[str, Any]], float | None]
    higher_is_better: bool = False


def _slam(key: str) -> Callable[[dict[str, Any]], float | None]:
    return lambda r: r.get("slam", {}).get(key)


FIGURES = (
    Figure("dsm_nmad_as_georeferenced_px", _slam("dsm_nmad_as_georeferenced_px")),
    Figure("dsm_nmad_as_georeferenced_m", _slam("dsm_nmad_as_georeferenced_m")),
    Figure("dsm_bias_as_georeferenced_px", _slam("dsm_bias_as_georeferenced_px")),
    Figure("dsm_nmad_coregistered_px", _slam("dsm_nmad_coregistered_px")),
    Figure("dsm_nmad_coregistered_m", _slam("dsm_nmad_coregistered_m")),
    Figure("completeness", _slam("completeness"), higher_is_better=True),
    Figure(
        "trajectory_rmse_m",
        lambda r: r.get("slam", {}).get("trajectory", {}).get("rmse_after_similarity_m"),
    ),
    Figure(
        "trajectory_rmse_georeferenced_m",
        lambda r: r.get("slam", {}).get("trajectory", {}).get("absolute_rmse_m"),
    ),
    Figure(
        "georef_residual_h_m",
        lambda r: r.get("slam", {}).get("georeference", {}).get("worst_rms_h_m"),
    ),
    Figure(
        "georef_within_stated_accuracy",
        lambda r: _as_number(
            r.get("slam", {}).get("georeference", {}).get("all_within_stated_accuracy")
        ),
        higher_is_better=True,
    ),
    Figure("slam_wall_s", _slam("wall_seconds")),
    Figure(
        "reconstruct_stage_s",
        lambda r: r.get("slam", {}).get("stage_seconds", {}).get("reconstruct"),
    ),
    Figure("real_time_factor", _slam("real_time_factor_reconstruct"), higher_is_better=True),
    Figure("real_time_factor_pipeline", _slam("real_time_factor_pipeline"), higher_is_better=True),
    Figure(
        "sfm_over_slam_wall_time",
        lambda r: r.get("sfm_over_slam_wall_time"),
        higher_is_better=True,
    ),
    # The reference's own result: a ratio over sfm runs that broke apart flatters slam.
    Figure(
        "sfm_dsm_nmad_as_georeferenced_px",
        lambda r: r.get("sfm", {}).get("dsm_nmad_as_georeferenced_px"),
    ),
    Figure(
        "sfm_quality_passed",
        lambda r: _as_number(r.get("sfm", {}).get("quality_passed")),
        higher_is_better=True,
    ),
)


@dataclass(frozen=True)
class Target:
    """A target on one statistic of one figure, for some groups."""

    figure: str
    stat: str
    bound: float
    higher_is_better: bool = False
    scenario: str | None = None  # None: every scenario
    gnss: str | None = None  # None: either GNSS mode

    def applies(self, scenario: str, gnss: str) -> bool:
        return self.scenario in (None, scenario) and self.gnss in (None, gnss)

    def label(self) -> str:
        return f"{self.stat} {'>=' if self.higher_is_better else '<='} {self.bound:g}"


TARGETS = (
    Target("success_pct", "all", 95.0, higher_is_better=True),
    Target("dsm_nmad_as_georeferenced_px", "median", 2.0, gnss="rtk"),
    Target("dsm_nmad_as_georeferenced_px", "p90", 3.0, gnss="rtk"),
    Target("dsm_nmad_coregistered_px", "p90", 2.0),
    Target("trajectory_rmse_m", "p90", 0.5, scenario="hillslope"),
    Target("sfm_over_slam_wall_time", "median", 10.0, higher_is_better=True),
    # The bar is the whole pipeline's (video seconds over the wall time of every
    # stage), not the reconstruction stage's alone.
    Target("real_time_factor_pipeline", "median", 1.0, higher_is_better=True),
)


def _as_number(flag: bool | None) -> float | None:
    return None if flag is None else float(flag)


def stats(values: list[float | None], higher_is_better: bool = False) -> dict[str, Any]:
    """Median, p90 and worst of the values that exist, and how many there are. p90 is
    the 90th percentile on the worse side (the 10th when higher is better)."""
    a = np.asarray([v for v in values if v is not None], dtype=np.float64)
    a = a[np.isfinite(a)]
    if a.size == 0:
        return {"n": 0, "median": None, "p90": None, "worst": None}
    return {
        "n": int(a.size),
        "median": round(float(np.median(a)), 4),
        "p90": round(float(np.percentile(a, 10 if higher_is_better else 90)), 4),
        "worst": round(float(a.min() if higher_is_better else a.max()), 4),
    }


# An RTK flight whose DSM is further from the truth than this (DSM pixels NMAD, as
# georeferenced: the p90 target) while its georeference claims the log's accuracy is a
# miss its report does not tell.
SILENT_MISS_PX = 3.0


def silent_miss(record: dict[str, Any]) -> bool:
    """An RTK flight off by more than SILENT_MISS_PX whose segments all passed the check
    against the log's stated accuracy and whose dense heights passed their agreement
    check (or were not checked): nothing in its report says it is off."""
    slam = record.get("slam", {})
    nmad = slam.get("dsm_nmad_as_georeferenced_px")
    within = slam.get("georeference", {}).get("all_within_stated_accuracy")
    noisy = slam.get("height_agreement_passed") is False
    rtk = record["conditions"].get("gnss") == "rtk"
    return bool(rtk and nmad is not None and nmad > SILENT_MISS_PX and within and not noisy)


def summarize_group(records: list[dict[str, Any]]) -> dict[str, Any]:
    """One group's success and the statistics of every figure over its successes."""
    ok = [r for r in records if r.get("success")]
    return {
        "flights": len(records),
        "succeeded": len(ok),
        "success_pct": round(100.0 * len(ok) / len(records), 1) if records else None,
        "failures": [
            {"seed": r["conditions"]["seed"], **r["slam"].get("failure", {})}
            for r in records
            if not r.get("success")
        ],
        "silent_misses": [r["conditions"]["seed"] for r in records if silent_miss(r)],
        "quality_failed": [
            r["conditions"]["seed"]
            for r in records
            if r.get("slam", {}).get("quality_passed") is False
        ],
        "sfm": _sfm_subset(records),
        "figures": {f.name: stats([f.get(r) for r in ok], f.higher_is_better) for f in FIGURES},
    }


def _sfm_subset(records: list[dict[str, Any]]) -> dict[str, Any]:
    """The flights also run with sfm: how many, and why sfm failed where it did (the
    wall-time ratio needs both methods to succeed)."""
    runs = [r for r in records if "sfm" in r]
    return {
        "runs": len(runs),
        "succeeded": sum(1 for r in runs if r["sfm"]["success"]),
        "failures": [
            {"seed": r["conditions"]["seed"], **r["sfm"]["failure"]}
            for r in runs
            if not r["sfm"]["success"]
        ],
    }


def judge(group: dict[str, Any], scenario: str, gnss: str) -> list[dict[str, Any]]:
    """Each target that applies to the group: its value and met / not met (n/a when the
    group has no value for it, e.g. no sfm run)."""
    out = []
    for t in TARGETS:
        if not t.applies(scenario, gnss):
            continue
        if t.figure == "success_pct":
            value = group["success_pct"]
        else:
            value = group["figures"][t.figure][t.stat]
        if value is None:
            status = "n/a"
        elif t.higher_is_better:
            status = "met" if value >= t.bound else "not met"
        else:
            status = "met" if value <= t.bound else "not met"
        out.append({"figure": t.figure, "target": t.label(), "value": value, "status": status})
    return out


def summarize(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Per scenario x GNSS mode ("paper-mounds/rtk" ...): the group and its targets."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in records:
        c = r["conditions"]
        groups.setdefault(f"{c['scenario']}/{c['gnss']}", []).append(r)
    out = {}
    for key in sorted(groups):
        scenario, gnss = key.split("/")
        group = summarize_group(groups[key])
        group["targets"] = judge(group, scenario, gnss)
        out[key] = group
    return out


# A flight without any of the harder conditions.
NO_CONDITION = "none"


def by_condition(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Per harder condition drawn (the conditions' `drawn` list; NO_CONDITION for flights
    without one): the group's success and figures, with the seeds it holds."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in records:
        for name in r["conditions"].get("drawn") or [NO_CONDITION]:
            groups.setdefault(name, []).append(r)
    out = {}
    for name, group in groups.items():
        summary = summarize_group(group)
        summary["seeds"] = [r["conditions"]["seed"] for r in group]
        out[name] = summary
    return out


# The figures the per-condition table prints (the JSON has them all).
CONDITION_FIGURES = (
    "dsm_nmad_as_georeferenced_px",
    "dsm_bias_as_georeferenced_px",
    "dsm_nmad_coregistered_px",
    "completeness",
    "trajectory_rmse_m",
    "georef_residual_h_m",
    "real_time_factor_pipeline",
)


def condition_table(groups: dict[str, Any]) -> str:
    """The printed per-condition table: success, and median / p90 / worst of the main
    figures."""
    lines = ["\nby condition (every scenario and GNSS mode):"]
    for name, group in groups.items():
        lines.append(
            f"  {name}: seeds {_seeds(group['seeds'])}; succeeded {group['succeeded']} "
            f"of {group['flights']}"
        )
        for failure in group["failures"]:
            lines.append(f"    failed seed {failure['seed']}: {failure.get('message', '')[:160]}")
        for failure in group["sfm"]["failures"]:
            lines.append(f"    sfm failed seed {failure['seed']}: {failure['message'][:160]}")
        for figure in CONDITION_FIGURES:
            st = group["figures"][figure]
            cells = " ".join(_cell(st[k]) for k in ("median", "p90", "worst"))
            lines.append(f"    {figure:34s} {st['n']:3d} {cells}")
    return "\n".join(lines)


def table(summary: dict[str, Any]) -> str:
    """The printed table: per group, each figure's median / p90 / worst and the targets."""
    lines = []
    for key, group in summary.items():
        lines.append(
            f"\n{key}: n={group['flights']}, succeeded {group['succeeded']} "
            f"({group['success_pct']:.0f} %)"
        )
        for failure in group["failures"]:
            lines.append(f"  failed seed {failure['seed']}: {failure.get('message', '')[:160]}")
        if group.get("quality_failed"):
            lines.append(f"  quality verdict failed: seeds {_seeds(group['quality_failed'])}")
        if group.get("silent_misses"):
            lines.append(
                f"  off by more than {SILENT_MISS_PX:g} px with nothing in the report "
                f"(within the stated accuracy, heights agreeing): "
                f"seeds {_seeds(group['silent_misses'])}"
            )
        sfm = group["sfm"]
        if sfm["runs"]:
            lines.append(f"  sfm subset: {sfm['succeeded']} of {sfm['runs']} succeeded")
        for failure in sfm["failures"]:
            lines.append(f"  sfm failed seed {failure['seed']}: {failure['message'][:160]}")
        lines.append(f"  {'figure':34s} {'n':>3s} {'median':>9s} {'p90':>9s} {'worst':>9s}")
        for name, s in group["figures"].items():
            cells = " ".join(_cell(s[k]) for k in ("median", "p90", "worst"))
            lines.append(f"  {name:34s} {s['n']:3d} {cells}")
        for t in group["targets"]:
            value = "-" if t["value"] is None else f"{t['value']:g}"
            lines.append(f"  target {t['figure']} {t['target']}: {value} -> {t['status']}")
    return "\n".join(lines)


def _cell(v: float | None) -> str:
    return f"{'-':>9s}" if v is None else f"{v:9.3f}"


def _seeds(seeds: list[int]) -> str:
    return ", ".join(str(seed) for seed in seeds)

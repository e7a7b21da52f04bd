"""`slidewatch bench photos`: georeferencing photo sets with consumer GPS.

    slidewatch bench photos --json benchmarks/results/photos.json
    slidewatch bench photos --json OUT.json --full 3 --work-dir data/bench-photos

A subcommand of the `bench` group (worker/commands/bench.py).

Measure where you did not tune: the robust fit (worker/pipeline/robust_fit.py) and its
constants were chosen on the simulator's "consumer" GNSS model (worker/simulator/gnss.py),
so its figures there are on fitted data. The "field" model (worker/simulator/gnss_field.py:
stepped geometry bias, barometric random walk and ramp, latency, spatially clustered
multipath, time-tag slips, Student-t noise) was built independently and nothing was tuned
on it: those figures are held out. `--gnss-model both` (the default) reports both, each
labelled.

Georeferencing only (the default): each seed flies a lawnmower photo survey (`--lines`
lines of `--photos-per-line` photos, one every `--interval-s` seconds), draws the photos'
GPS from the model and stands in for SfM with the true camera centres moved into an
arbitrary frame (random rotation, scale, offset) plus `--sfm-noise-m` of noise: what is
measured is the georeferencing, not the rendering or COLMAP. Both fits run on the same data:

- `robust`: what photo sets use (`robust_fit.georeference_photos`);
- `similarity`: the fit of video trajectories (`georef.georeference`), which photo
  sets used before.

Per model and fit, median / p90 / worst over the seeds: horizontal and vertical RMS error
of the georeferenced camera centres against the TRUE positions (not the noisy GPS; the
flight's mean GNSS error, which no fit without ground control can see, included), the same
beyond that mean, and the fit's residuals (model minus GPS, RMS over the photos the fit
kept: the robust fit leaves its outliers out, the similarity keeps every photo), the share
of sets below the issue's 3 m, and the time; for the robust fit the outlier photos flagged
against those planted (the gross part of a photo's GPS error, outlier fix or multipath
or time-tag slip, more than 10 m horizontally): recall and false flags.

`--full N`: end to end, rendering and the real reconstruction
(worker/commands/bench_photos_full.py).

The JSON has one block per model under "models"; its top level also repeats the first
model's block (consumer, by default) under the keys the file had before both models.
"""

from __future__ import annotations

import json
import time
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import click
import numpy as np
from pyproj import Transformer
from scipy.spatial.transform import Rotation

from worker.commands.bench_photos_full import run_full
from worker.commands.photo_bench_figures import (
    LABELS,
    MODELS,
    PLANTED_M,
    TARGET_M,
    flag_counts,
    fmt,
    model_of,
    outlier_figures,
    rms,
    share_below,
    summary,
)
from worker.pipeline.attitude import rotation_world_from_camera
from worker.pipeline.georef import GeorefOptions, georeference
from worker.pipeline.ingest.flight_log import build_flight_log
from worker.pipeline.robust_fit import georeference_photos
from worker.pipeline.trajectory import Trajectory
from worker.simulator.gnss_field import PositionFn, simulate_flight_gnss

EPSG = 32632
ORIGIN = np.array([446_000.0, 5_253_000.0, 500.0])
FITS = ("robust", "similarity")


def _survey(
    lines: int, per_line: int, spacing_m: float, interval_s: float, speed_m_s: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(photo times, true camera centres ENU, headings): a lawnmower at 80 m."""
    along = speed_m_s * interval_s
    times, pts, heads = [], [], []
    t = 0.0
    for k in range(lines):
        xs = np.arange(per_line) * along
        if k % 2:
            xs = xs[::-1]
        for x in xs:
            times.append(t)
            pts.append([x, k * spacing_m, 80.0])
            heads.append(90.0 if k % 2 == 0 else 270.0)
            t += interval_s
        # The turn to the next line.
        t += spacing_m / speed_m_s
    return np.array(times), np.array(pts) + ORIGIN, np.array(heads)


def _track(times: np.ndarray, true: np.ndarray) -> PositionFn:
    """The aircraft's true position at any time: straight between the photos (the turns
    too), hovering before the first and after the last (the field model's multipath and
    time-tag slips depend on where it is and how it moves)."""

    def position_at(t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        return np.stack([np.interp(t, times, true[:, k] - ORIGIN[k]) for k in range(3)], -1)

    return position_at


def _seed_rng(seed: int, model: str) -> np.random.Generator:
    # consumer keeps the stream its figures always had; field gets one of its own.
    if model == "consumer":
        return np.random.default_rng(seed)
    return np.random.default_rng(np.random.SeedSequence([seed, zlib.crc32(model.encode())]))


@dataclass(frozen=True)
class PhotoSurvey:
    """The simulated photo flight: `lines` lines of `photos_per_line` photos,
    `line_spacing_m` apart, one photo every `interval_s` at `speed_m_s`, and the SfM
    stand-in's noise."""

    lines: int = 4
    photos_per_line: int = 10
    line_spacing_m: float = 40.0
    interval_s: float = 2.0
    speed_m_s: float = 8.0
    sfm_noise_m: float = 0.1


def run_seed(seed: int, plan: PhotoSurvey, model: str = "consumer") -> dict[str, Any]:
    """One simulated photo set under GNSS `model`, both fits; figures in metres."""
    rng = _seed_rng(seed, model)
    times, true, heads = _survey(
        plan.lines, plan.photos_per_line, plan.line_spacing_m, plan.interval_s, plan.speed_m_s
    )
    gnss = simulate_flight_gnss(model_of(model), -5.0, times[-1] + 5.0, _track(times, true), rng)
    err = gnss.error_at(times)
    gross = np.hypot(*gnss.outlier_at(times)[:, :2].T)
    planted = np.flatnonzero(gross > PLANTED_M)
    logged = true + err
    lon, lat = Transformer.from_crs(f"EPSG:{EPSG}", "EPSG:4326", always_xy=True).transform(
        logged[:, 0], logged[:, 1]
    )
    rows = [
        {"line": i + 2, "t": float(times[i]), "lat": lat[i], "lon": lon[i], "alt": logged[i, 2]}
        for i in range(len(times))
    ]
    log = build_flight_log("photos.csv", "generic_csv", rows)
    # SfM stand-in: the true centres in an arbitrary frame, with reconstruction noise.
    rot = Rotation.random(random_state=seed).as_matrix()
    scale = float(rng.uniform(0.02, 0.5))
    shift = rng.normal(0.0, 10.0, 3)
    noisy = true + rng.normal(0.0, plan.sfm_noise_m, true.shape)
    local = ((noisy - true.mean(axis=0)) @ rot) * scale + shift
    r_local = np.einsum(
        "ji,njk->nik", rot, rotation_world_from_camera(heads, -90.0, np.zeros_like(heads))
    )
    traj = Trajectory(times, local, r_local, np.ones(len(times), bool))
    names = [f"DJI_{i + 1:04d}.JPG" for i in range(len(times))]
    out: dict[str, Any] = {"seed": seed, "photos": len(times), "planted": len(planted)}
    # The flight's mean GNSS error over the good photos: what no fit without ground
    # control can see; errors beyond it measure the fit itself.
    good = np.ones(len(times), bool)
    good[planted] = False
    bias = err[good].mean(axis=0)
    t0 = time.perf_counter()
    robust = georeference_photos(traj, names, log, 0.0, GeorefOptions(seed=seed))
    out["robust_seconds"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    plain = georeference(traj, log, 0.0, GeorefOptions(seed=seed))
    out["similarity_seconds"] = time.perf_counter() - t0
    for fit, res in (("robust", robust), ("similarity", plain)):
        placed = res.apply(local)
        out[f"{fit}_h"], out[f"{fit}_v"] = rms(placed - true)
        out[f"{fit}_h_beyond_bias"], out[f"{fit}_v_beyond_bias"] = rms(placed - true - bias)
        # Model minus GPS over the photos the fit kept (the robust fit's residual
        # statistics leave its outliers out; the similarity keeps every photo).
        r = res.residuals
        out[f"{fit}_residual_h"] = float(np.hypot(r["rms_east"], r["rms_north"]))
        out[f"{fit}_residual_v"] = float(r["rms_up"])
    flagged = {p["name"] for p in robust.outliers}
    out.update(flag_counts(flagged, names, gross))
    out["gnss_mean_error_h"] = float(np.hypot(bias[0], bias[1]))
    return out


def model_block(model: str, runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The figures of one GNSS model over its seeds."""
    block: dict[str, Any] = {"label": LABELS[model], "gnss": model_of(model).to_dict()}
    for fit in FITS:
        h = [r[f"{fit}_h"] for r in runs]
        res_h = [r[f"{fit}_residual_h"] for r in runs]
        block[fit] = {
            "horizontal_rms_m": summary(h),
            "vertical_rms_m": summary([r[f"{fit}_v"] for r in runs]),
            "horizontal_rms_beyond_bias_m": summary([r[f"{fit}_h_beyond_bias"] for r in runs]),
            "vertical_rms_beyond_bias_m": summary([r[f"{fit}_v_beyond_bias"] for r in runs]),
            "residual_horizontal_rms_m": summary(res_h),
            "residual_vertical_rms_m": summary([r[f"{fit}_residual_v"] for r in runs]),
            "share_of_sets_below_3m": {
                "horizontal_error": share_below(h, TARGET_M),
                "horizontal_residual": share_below(res_h, TARGET_M),
            },
            "seconds_per_set": summary([r[f"{fit}_seconds"] for r in runs]),
        }
    block["robust"]["outliers"] = outlier_figures(runs)
    block["gnss_mean_error_h_m"] = summary([r["gnss_mean_error_h"] for r in runs])
    block["runs"] = [
        {k: round(v, 4) if isinstance(v, float) else v for k, v in r.items()} for r in runs
    ]
    return block


def print_block(model: str, block: dict[str, Any], seeds: int, seconds: float) -> None:
    click.echo(f"== {model} GNSS ({block['label']}), {seeds} seeds, {seconds:.1f} s")
    click.echo("   median / p90 / worst (m)")
    for fit in FITS:
        f = block[fit]
        click.echo(
            f"   {fit:10s} error vs truth: horizontal {fmt(f['horizontal_rms_m'])}, vertical "
            f"{fmt(f['vertical_rms_m'])} | beyond the flight's mean GNSS error: horizontal "
            f"{fmt(f['horizontal_rms_beyond_bias_m'])}, vertical "
            f"{fmt(f['vertical_rms_beyond_bias_m'])}"
        )
        share = f["share_of_sets_below_3m"]
        click.echo(
            f"   {'':10s} residual (model - GPS, photos kept): horizontal "
            f"{fmt(f['residual_horizontal_rms_m'])}, vertical "
            f"{fmt(f['residual_vertical_rms_m'])} | sets below 3 m: error "
            f"{share['horizontal_error']:.0%}, residual {share['horizontal_residual']:.0%} | "
            f"{f['seconds_per_set']['median']:.3f} s per set"
        )
    o = block["robust"]["outliers"]
    recall = "n/a" if o["recall"] is None else f"{o['recall']:.0%}"
    click.echo(
        f"   outliers: the robust fit flagged {o['flagged_and_planted']} of {o['planted']} "
        f"planted (> 10 m; recall {recall}), {o['flagged_moderate']} of {o['moderate']} "
        f"moderate (1-10 m), {o['false_flags']} false flags (no gross error) in "
        f"{o['sets_with_a_false_flag']} of {seeds} sets; flight's mean GNSS error "
        f"(horizontal) {fmt(block['gnss_mean_error_h_m'])}"
    )


def _run_fast(models: list[str], seeds: int, plan: PhotoSurvey) -> dict[str, Any]:
    """The georeferencing-only bench over `seeds` seeds per model; prints its figures."""
    start = time.perf_counter()
    result: dict[str, Any] = {
        "options": {"seeds": seeds, **asdict(plan)},
        "note": "RMS error of the georeferenced camera centres against the true positions "
        "(m), the flight's mean GNSS error included; residuals are model minus GPS over the "
        "photos the fit kept; SfM simulated (true centres + noise)",
        "models": {},
    }
    for model in models:
        t0 = time.perf_counter()
        runs = [run_seed(s, plan, model) for s in range(seeds)]
        block = model_block(model, runs)
        block["seconds"] = round(time.perf_counter() - t0, 3)
        result["models"][model] = block
        print_block(model, block, seeds, block["seconds"])
    # The keys the file had before it held two models: the first model's figures.
    first = result["models"][models[0]]
    result.update(
        {
            "gnss": first["gnss"],
            "robust": first["robust"],
            "similarity": first["similarity"],
            "gnss_bias_h_m": first["gnss_mean_error_h_m"],
            "runs": first["runs"],
        }
    )
    result["seconds"] = round(time.perf_counter() - start, 3)
    click.echo(f"{len(models)} model(s) x {seeds} seeds in {result['seconds']:.1f} s")
    return result


# -- end to end (--full) ------------------------------------------------------------------
@click.command("photos")
@click.option("--json", "json_path", type=click.Path(path_type=Path), required=True)
@click.option(
    "--gnss-model",
    type=click.Choice([*MODELS, "both"]),
    default="both",
    show_default=True,
    help="consumer: the model the fit was tuned on (fitted); field: built independently, "
    "nothing tuned on it (held out).",
)
@click.option("--seeds", type=int, default=100, show_default=True)
@click.option("--lines", type=int, default=4, show_default=True)
@click.option("--photos-per-line", type=int, default=10, show_default=True)
@click.option("--line-spacing-m", type=float, default=40.0, show_default=True)
@click.option("--interval-s", type=float, default=2.0, show_default=True)
@click.option("--speed-m-s", type=float, default=8.0, show_default=True)
@click.option("--sfm-noise-m", type=float, default=0.1, show_default=True)
@click.option(
    "--full",
    type=click.IntRange(0, None),
    default=0,
    show_default=True,
    help="End to end instead: N seeds per model of rendered photos, sfm reconstruction, DSM.",
)
@click.option(
    "--work-dir",
    type=click.Path(path_type=Path),
    default=Path("data/bench-photos"),
    show_default=True,
    help="--full: each seed's simulation and reconstruction, kept for re-runs.",
)
@click.option(
    "--full-scenario",
    type=click.Choice(["hillslope", "paper-mounds"]),
    default="hillslope",
    show_default=True,
)
@click.option("--full-width", type=int, default=912, show_default=True)
@click.option("--full-height", type=int, default=608, show_default=True)
@click.option("--first-seed", type=int, default=1, show_default=True, help="--full only.")
@click.option("--fresh", is_flag=True, help="--full: run every reconstruction again whole.")
def photos(
    json_path: Path,
    gnss_model: str,
    seeds: int,
    lines: int,
    photos_per_line: int,
    line_spacing_m: float,
    interval_s: float,
    speed_m_s: float,
    sfm_noise_m: float,
    full: int,
    work_dir: Path,
    full_scenario: str,
    full_width: int,
    full_height: int,
    first_seed: int,
    fresh: bool,
) -> None:
    """Photo sets with consumer GPS: the robust fit against the trajectory fit, against
    the truth, on the fitted (consumer) and the held-out (field) GNSS model."""
    models = list(MODELS) if gnss_model == "both" else [gnss_model]
    if full:
        result = run_full(
            models, full, first_seed, work_dir, full_scenario, full_width, full_height, fresh
        )
    else:
        plan = PhotoSurvey(
            lines, photos_per_line, line_spacing_m, interval_s, speed_m_s, sfm_noise_m
        )
        result = _run_fast(models, seeds, plan)
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")

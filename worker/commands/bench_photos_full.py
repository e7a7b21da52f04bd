"""`slidewatch bench photos --full N`: photo sets end to end.

`--full N`: end to end, for N seeds per model (from `--first-seed`): the simulator renders
a photo survey (`--full-scenario`, default the real-scale hillslope at 100 m: 24 photos in
two lines; `--full-width` x `--full-height`, default 912 x 608), the real reconstruction
runs (method sfm: COLMAP, the robust fit, the bundle adjustment, the DSM), and per seed
and as median / p90 / worst: the georeferencing residuals (georeference.json: the robust
fit's over the photos kept, and after the bundle adjustment), the camera positions
against the true ones (the simulator's images.csv), outlier photos flagged against those
planted (here: a photo whose GPS error, read back from its EXIF, is more than 10 m
horizontally from the flight's median error; 5-10 m is "moderate", a flag on a photo
within 5 m a false flag), the DSM's `overlap_coverage` and `overlap_area_m2` (dsm.json;
"n/a" where absent), its NMAD against the truth DSM (as georeferenced, and with the DSM
moved by the similarity of the estimated cameras onto the true ones: the reconstruction's
own error), and the stage times (about 2.5 minutes a seed on 2 cores). Each
seed's simulation and reconstruction stay under `--work-dir`; a re-run reuses the
simulation and resumes the reconstruction at its first stage without a result
(`--fresh` runs it again whole).
"""

from __future__ import annotations

import csv
import json
import time
from pathlib import Path
from typing import Any

import click
import numpy as np
from pyproj import Transformer

from worker.commands.photo_bench_figures import (
    LABELS,
    PLANTED_M,
    flag_counts,
    fmt,
    outlier_figures,
    rms,
    summary,
)
from worker.pipeline.georef import Similarity, umeyama
from worker.pipeline.trajectory import read_trajectory_csv

FULL_CLEAN_M = 5.0


def _summary_low_worst(values: list[float]) -> dict[str, float]:
    """For figures where less is worse (coverage): median, p10 and the least."""
    a = np.asarray([v for v in values if v is not None], dtype=np.float64)
    if a.size == 0:
        return {"median": float("nan"), "p10": float("nan"), "worst": float("nan")}
    return {
        "median": round(float(np.median(a)), 4),
        "p10": round(float(np.percentile(a, 10)), 4),
        "worst": round(float(a.min()), 4),
    }


def _read_json(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else {}


def _truth_photos(images_csv: Path) -> tuple[list[str], np.ndarray, np.ndarray]:
    """The simulator's true camera centres: names, times (s), (n, 3) e, n, u."""
    with open(images_csv, encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    names = [r["image"] for r in rows]
    t = np.array([float(r["t_s"]) for r in rows])
    enu = np.array([[float(r["e"]), float(r["n"]), float(r["u"])] for r in rows])
    return names, t, enu


def _photo_gps(folder: Path, names: list[str], crs: str) -> np.ndarray:
    """(n, 3) each photo's GPS position as its EXIF gives it, in `crs` (e, n, alt)."""
    from worker.pipeline.ingest.images import read_image_metadata

    to_crs = Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    out = np.full((len(names), 3), np.nan)
    for i, name in enumerate(names):
        meta = read_image_metadata(folder / name)
        if meta.lat is None or meta.lon is None:
            continue
        e, n = to_crs.transform(meta.lon, meta.lat)
        out[i] = [e, n, np.nan if meta.alt is None else meta.alt]
    return out


def _camera_positions(trajectory_csv: Path) -> tuple[np.ndarray, np.ndarray]:
    """The reconstruction's georeferenced camera centres: times (s), (n, 3)."""
    traj = read_trajectory_csv(trajectory_csv)
    return traj.t, traj.positions


def _dsm_error(recon: Path, truth_dsm: Path, to_truth: Similarity | None = None) -> dict[str, Any]:
    """DSM minus the truth DSM at the measured (not inpainted) cells: median and NMAD.
    `to_truth` moves the DSM first (the similarity of the cameras onto their true
    positions: what is left is the reconstruction's error, not the GNSS's)."""
    import rasterio

    from worker.pipeline.dsm_export import FILLED_MEASURED

    with rasterio.open(recon / "dsm.tif") as src:
        dsm = src.read(1, masked=True).filled(np.nan)
        transform = src.transform
    with rasterio.open(recon / "dsm_filled.tif") as src:
        measured = src.read(1) == FILLED_MEASURED
    rows, cols = np.nonzero(measured & np.isfinite(dsm))
    x, y = transform * (cols + 0.5, rows + 0.5)
    pts = np.column_stack([x, y, dsm[rows, cols]])
    if to_truth is not None:
        pts = to_truth.apply(pts)
    with rasterio.open(truth_dsm) as src:
        truth = src.read(1, masked=True).filled(np.nan)
        c, r = ~src.transform * (pts[:, 0], pts[:, 1])
    c, r = np.floor(c).astype(int), np.floor(r).astype(int)
    ok = (c >= 0) & (c < truth.shape[1]) & (r >= 0) & (r < truth.shape[0])
    diff = pts[ok, 2] - truth[r[ok], c[ok]]
    diff = diff[np.isfinite(diff)]
    if diff.size == 0:
        return {"cells": 0}
    med = float(np.median(diff))
    return {
        "median_m": round(med, 3),
        "nmad_m": round(1.4826 * float(np.median(np.abs(diff - med))), 3),
        "cells": int(diff.size),
    }


def _simulate(
    model: str, seed: int, sim: Path, scenario: str, width: int, height: int
) -> tuple[Any, float | None]:
    """The seed's rendered photo survey: simulated now, or the one kept from before."""
    from worker.simulator.manifest import Manifest
    from worker.simulator.simulate import SimulationOptions, simulate_scenario

    if (sim / "manifest.json").is_file():
        data = _read_json(sim / "manifest.json")
        kept = data.get("options", {})
        wanted = {"gnss": model, "image_width": width, "image_height": height}
        if data.get("scenario") != scenario or any(kept.get(k) != v for k, v in wanted.items()):
            raise click.ClickException(
                f"{sim} holds a simulation with other options ({data.get('scenario')}, "
                f"{kept.get('gnss')}, {kept.get('image_width')}x{kept.get('image_height')}): "
                "remove it or choose another --work-dir"
            )
        return Manifest(root=sim, data=data), None
    t0 = time.perf_counter()
    options = SimulationOptions(
        seed=seed,
        steps=1,
        survey="images",
        gnss=model,
        image_width=width,
        image_height=height,
        csv_units="meters",
        registration=False,
        # One rendering process: the machine is shared.
        workers=1,
    )
    manifest = simulate_scenario(scenario, sim, options)
    return manifest, time.perf_counter() - t0


def _reconstruct(images: Path, recon: Path, fresh: bool) -> tuple[float, str | None, str | None]:
    """Run the sfm reconstruction, resuming at the first stage without a result.
    (wall seconds, the stage it started from or None when nothing was left, error)."""
    from worker.pipeline.reconstruction import (
        STAGES,
        ReconstructionInputs,
        ReconstructionOptions,
        reconstruct_survey,
    )

    missing = [s for s in STAGES if fresh or not (recon / f"{s}.json").is_file()]
    if not missing:
        return 0.0, None, None
    start = missing[0]
    t0 = time.perf_counter()
    try:
        reconstruct_survey(
            ReconstructionInputs(images=str(images)),
            recon,
            ReconstructionOptions(method="sfm"),
            from_stage=start,
        )
    except Exception as exc:  # a failed seed is a figure, not the end of the bench
        return time.perf_counter() - t0, start, f"{type(exc).__name__}: {exc}"
    return time.perf_counter() - t0, start, None


def full_seed(
    model: str,
    seed: int,
    work_dir: Path,
    scenario: str,
    width: int,
    height: int,
    fresh: bool = False,
) -> dict[str, Any]:
    """One seed end to end: simulate (or reuse), reconstruct (or resume), measure."""
    root = work_dir / f"{model}-seed{seed}"
    manifest, sim_seconds = _simulate(model, seed, root / "sim", scenario, width, height)
    survey = manifest.steps[0]["surveys"][0]
    images = manifest.resolve(survey["images_dir"])
    recon = root / "recon"
    wall, started, error = _reconstruct(images, recon, fresh)
    out: dict[str, Any] = {
        "model": model,
        "seed": seed,
        "work_dir": str(root),
        "photos": survey["images"],
        # A kept simulation: the time it took then, as its manifest says.
        "simulation_seconds": round(
            sim_seconds
            if sim_seconds is not None
            else manifest.data.get("timings_s", {}).get("total", float("nan")),
            1,
        ),
        "simulation_reused": sim_seconds is None,
        "reconstruction_wall_seconds": round(wall, 1),
        "resumed_from_stage": started,
        "error": error,
    }
    from worker.pipeline.reconstruction import STAGES

    out["stage_seconds"] = {s: _read_json(recon / f"{s}.json").get("seconds") for s in STAGES}
    # From the stages' own results: the same figure whether this run or an earlier one
    # ran them.
    out["stages_seconds"] = sum(v for v in out["stage_seconds"].values() if v is not None)
    names, t_true, true = _truth_photos(manifest.resolve(survey["images_csv"]))
    gps = _photo_gps(images, names, manifest.data["crs"])
    err = gps - true
    # Without the simulator's internal track, a photo's gross error is how far its GPS
    # error lies from the flight's median one; "clean" here is within FULL_CLEAN_M (the
    # latency, bias steps and noise of the field model move good photos by metres).
    deviation = np.hypot(*(err[:, :2] - np.nanmedian(err[:, :2], axis=0)).T)
    gross = np.where(deviation > FULL_CLEAN_M, deviation, 0.0)
    good = deviation <= PLANTED_M
    bias = np.nanmean(err[good], axis=0)
    planted = {n for n, g in zip(names, gross, strict=True) if g > PLANTED_M}
    out["gnss_mean_error_h"] = float(np.hypot(bias[0], bias[1]))
    geo = _read_json(recon / "georeference.json")
    if geo:
        seg = geo["segments"][0]
        fit = seg["fit"]["residuals_m"]
        after = seg.get("residuals_after_m") or fit
        out["residual_fit_h"] = float(np.hypot(fit["rms_east"], fit["rms_north"]))
        out["residual_fit_v"] = float(fit["rms_up"])
        out["residual_after_ba_h"] = float(np.hypot(after["rms_east"], after["rms_north"]))
        out["residual_after_ba_v"] = float(after["rms_up"])
        flagged = {p["name"] for p in geo.get("photos") or [] if p["status"] == "outlier"}
        out.update(flag_counts(flagged, names, gross))
        out["flagged_names"] = sorted(flagged)
        out["planted_names"] = sorted(planted)
    to_truth = None
    if (recon / "trajectory.csv").is_file():
        t_est, est = _camera_positions(recon / "trajectory.csv")
        idx = np.clip(np.searchsorted(t_true, t_est), 1, len(t_true) - 1)
        idx = np.where(np.abs(t_true[idx - 1] - t_est) < np.abs(t_true[idx] - t_est), idx - 1, idx)
        close = np.abs(t_true[idx] - t_est) < 0.2
        d = est[close] - true[idx[close]]
        out["cameras_matched"] = int(close.sum())
        if close.any():
            out["camera_h"], out["camera_v"] = rms(d)
            out["camera_h_beyond_bias"], out["camera_v_beyond_bias"] = rms(d - bias)
        if close.sum() >= 3:
            to_truth = umeyama(est[close], true[idx[close]])
    dsm = _read_json(recon / "dsm.json")
    if dsm:
        out["overlap_coverage"] = dsm.get("overlap_coverage")
        out["overlap_area_m2"] = dsm.get("overlap_area_m2")
        out["completeness"] = (dsm.get("dsm") or {}).get("completeness")
        truth_dsm = manifest.resolve(manifest.steps[0]["truth"]["dsm"])
        if (recon / "dsm.tif").is_file() and (recon / "dsm_filled.tif").is_file():
            out["dsm_vs_truth"] = _dsm_error(recon, truth_dsm)
            if to_truth is not None:
                out["dsm_vs_truth_reconstruction_only"] = _dsm_error(recon, truth_dsm, to_truth)
    return out


def _na(value: Any, spec: str = ".2f") -> str:
    return "n/a" if value is None else format(value, spec)


def print_full_seed(r: dict[str, Any]) -> None:
    dsm = r.get("dsm_vs_truth") or {}
    shape = r.get("dsm_vs_truth_reconstruction_only") or {}
    stages = " ".join(f"{k} {_na(v, '.0f')}" for k, v in r["stage_seconds"].items())
    click.echo(
        f"   seed {r['seed']}: {r['photos']} photos | residual h fit {_na(r.get('residual_fit_h'))}"
        f" after BA {_na(r.get('residual_after_ba_h'))} m | cameras vs truth h "
        f"{_na(r.get('camera_h'))} v {_na(r.get('camera_v'))} m (beyond the mean GNSS error "
        f"h {_na(r.get('camera_h_beyond_bias'))} v {_na(r.get('camera_v_beyond_bias'))}) | "
        f"outliers {_na(r.get('flagged_planted'), 'd')} of {_na(r.get('planted'), 'd')} planted "
        f"flagged, {_na(r.get('flagged'), 'd')} flagged in all | overlap_coverage "
        f"{_na(r.get('overlap_coverage'), '.3f')} of {_na(r.get('overlap_area_m2'), '.0f')} m2 "
        f"| DSM vs truth NMAD {_na(dsm.get('nmad_m'))} m (median {_na(dsm.get('median_m'))}; "
        f"cameras moved onto the truth: {_na(shape.get('nmad_m'))}) | "
        f"simulation {_na(r['simulation_seconds'], '.0f')} s, stages [{stages}] s"
        + (f" | ERROR {r['error']}" if r.get("error") else "")
    )


def run_full(
    models: list[str],
    seeds: int,
    first_seed: int,
    work_dir: Path,
    scenario: str,
    width: int,
    height: int,
    fresh: bool,
) -> dict[str, Any]:
    """--full: `seeds` seeds per model end to end; prints per seed and the summaries."""
    start = time.perf_counter()
    result: dict[str, Any] = {
        "mode": "full",
        "options": {
            "seeds": seeds,
            "first_seed": first_seed,
            "scenario": scenario,
            "image_width": width,
            "image_height": height,
            "method": "sfm",
            "work_dir": str(work_dir),
        },
        "note": "residuals: georeference.json (robust fit over the photos kept, and after the "
        "bundle adjustment); cameras: trajectory.csv against the simulator's images.csv; "
        "planted outliers: photos whose EXIF GPS error is > 10 m horizontally from the "
        "flight's median error; DSM: dsm.json and dsm.tif against the truth DSM",
        "models": {},
    }
    for model in models:
        click.echo(f"== {model} GNSS ({LABELS[model]}), end to end, {scenario}")
        runs = []
        for seed in range(first_seed, first_seed + seeds):
            r = full_seed(model, seed, work_dir, scenario, width, height, fresh)
            print_full_seed(r)
            runs.append(r)
        keys = (
            "residual_fit_h",
            "residual_after_ba_h",
            "camera_h",
            "camera_v",
            "camera_h_beyond_bias",
            "camera_v_beyond_bias",
            "gnss_mean_error_h",
            "stages_seconds",
        )
        block: dict[str, Any] = {"label": LABELS[model]}
        for key in keys:
            block[key + ("" if key.endswith("seconds") else "_m")] = summary(
                [r[key] for r in runs if r.get(key) is not None]
            )
        block["dsm_nmad_m"] = summary(
            [r["dsm_vs_truth"]["nmad_m"] for r in runs if "nmad_m" in r.get("dsm_vs_truth", {})]
        )
        block["dsm_nmad_reconstruction_only_m"] = summary(
            [
                r["dsm_vs_truth_reconstruction_only"]["nmad_m"]
                for r in runs
                if "nmad_m" in r.get("dsm_vs_truth_reconstruction_only", {})
            ]
        )
        block["overlap_coverage"] = _summary_low_worst([r.get("overlap_coverage") for r in runs])
        block["overlap_area_m2"] = _summary_low_worst([r.get("overlap_area_m2") for r in runs])
        with_geo = [r for r in runs if "flagged" in r]
        block["outliers"] = outlier_figures(with_geo) if with_geo else None
        block["failed_seeds"] = [r["seed"] for r in runs if r.get("error")]
        block["runs"] = [
            {k: round(v, 4) if isinstance(v, float) else v for k, v in r.items()} for r in runs
        ]
        result["models"][model] = block
        o = block["outliers"] or {}
        cov = block["overlap_coverage"]
        click.echo(
            f"   median / p90 / worst: residual h (fit) {fmt(block['residual_fit_h_m'])}, "
            f"(after BA) {fmt(block['residual_after_ba_h_m'])} | cameras vs truth h "
            f"{fmt(block['camera_h_m'])}, v {fmt(block['camera_v_m'])} | DSM NMAD "
            f"{fmt(block['dsm_nmad_m'])} (cameras moved onto the truth "
            f"{fmt(block['dsm_nmad_reconstruction_only_m'])}) m | overlap_coverage median / "
            f"p10 / least {cov['median']:.3f} / {cov['p10']:.3f} / {cov['worst']:.3f} | outliers "
            f"{o.get('flagged_and_planted', 'n/a')} of {o.get('planted', 'n/a')} planted "
            f"flagged, {o.get('false_flags', 'n/a')} false | stages together "
            f"{fmt(block['stages_seconds'])} s"
        )
    result["seconds"] = round(time.perf_counter() - start, 1)
    click.echo(f"{len(models)} model(s) x {seeds} seeds end to end in {result['seconds']:.0f} s")
    return result

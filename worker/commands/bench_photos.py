"""`slidewatch bench photos`: georeferencing photo sets with consumer GPS.

    slidewatch bench photos --json benchmarks/results/photos.json

A subcommand of the `bench` group (worker/commands/bench.py). Each seed flies a
lawnmower photo survey (`--lines` lines of `--photos-per-line` photos, one every
`--interval-s` seconds), draws the photos' GPS from the simulator's "consumer" GNSS model
(worker/simulator/gnss.py: bias of metres, altitude drifting by tens of metres within a
minute, outlier fixes tens of metres off) and stands in for SfM with the true camera
centres moved into an arbitrary frame (random rotation, scale, offset) plus
`--sfm-noise-m` of noise: what is measured is the georeferencing, not the rendering
or COLMAP (the end-to-end tests run those). Both fits run on the same data:

- `robust`: what photo sets use (`robust_fit.georeference_photos`);
- `similarity`: the fit of video trajectories (`georef.georeference`), which photo
  sets used before.

Per fit: horizontal and vertical RMS error of the georeferenced camera centres against
the TRUE positions (not the noisy GPS; the flight's common GNSS bias, which no fit without
ground control can see, included) as median / p90 / worst over the seeds; for the robust
fit the outlier photos flagged against those planted (a GPS error from an outlier fix of
more than 10 m) and the time.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import click
import numpy as np
from pyproj import Transformer
from scipy.spatial.transform import Rotation

from worker.pipeline.attitude import rotation_world_from_camera
from worker.pipeline.georef import GeorefOptions, georeference
from worker.pipeline.ingest.flight_log import build_flight_log
from worker.pipeline.robust_fit import georeference_photos
from worker.pipeline.trajectory import Trajectory
from worker.simulator.gnss import GnssErrorModel, simulate_gnss

EPSG = 32632
ORIGIN = np.array([446_000.0, 5_253_000.0, 500.0])
PLANTED_M = 10.0  # an outlier fix this far off (horizontally) counts as planted


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


def _rms(d: np.ndarray) -> tuple[float, float]:
    """Horizontal and vertical RMS of (n, 3) errors."""
    return (
        float(np.sqrt((d[:, :2] ** 2).sum(axis=1).mean())),
        float(np.sqrt((d[:, 2] ** 2).mean())),
    )


def run_seed(
    seed: int,
    lines: int,
    per_line: int,
    spacing_m: float,
    interval_s: float,
    speed_m_s: float,
    sfm_noise_m: float,
) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    times, true, heads = _survey(lines, per_line, spacing_m, interval_s, speed_m_s)
    gnss = simulate_gnss(GnssErrorModel.named("consumer"), -5.0, times[-1] + 5.0, rng)
    err = gnss.error_at(times)
    planted = np.flatnonzero(np.hypot(*gnss.outlier_at(times)[:, :2].T) > PLANTED_M)
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
    noisy = true + rng.normal(0.0, sfm_noise_m, true.shape)
    local = ((noisy - true.mean(axis=0)) @ rot) * scale + shift
    r_local = np.einsum(
        "ji,njk->nik", rot, rotation_world_from_camera(heads, -90.0, np.zeros_like(heads))
    )
    traj = Trajectory(times, local, r_local, np.ones(len(times), bool))
    names = [f"DJI_{i + 1:04d}.JPG" for i in range(len(times))]
    out: dict[str, Any] = {"seed": seed, "photos": len(times), "planted": len(planted)}
    t0 = time.perf_counter()
    robust = georeference_photos(traj, names, log, 0.0, GeorefOptions(seed=seed))
    out["robust_seconds"] = time.perf_counter() - t0
    # The flight's mean GNSS error over the good photos: what no fit without ground
    # control can see; errors beyond it measure the fit itself.
    good = np.ones(len(times), bool)
    good[planted] = False
    bias = err[good].mean(axis=0)
    h, v = _rms(robust.apply(local) - true)
    out["robust_h_beyond_bias"], out["robust_v_beyond_bias"] = _rms(
        robust.apply(local) - true - bias
    )
    flagged = {p["name"] for p in robust.outliers}
    hits = len(flagged & {names[i] for i in planted})
    out.update({"robust_h": h, "robust_v": v, "flagged": len(flagged), "flagged_planted": hits})
    t0 = time.perf_counter()
    plain = georeference(traj, log, 0.0, GeorefOptions(seed=seed))
    out["similarity_seconds"] = time.perf_counter() - t0
    out["similarity_h"], out["similarity_v"] = _rms(plain.apply(local) - true)
    out["similarity_h_beyond_bias"], out["similarity_v_beyond_bias"] = _rms(
        plain.apply(local) - true - bias
    )
    out["gnss_bias_h"] = float(np.hypot(*gnss.bias_enu[:2]))
    return out


def _summary(values: list[float]) -> dict[str, float]:
    a = np.asarray(values)
    return {
        "median": round(float(np.median(a)), 3),
        "p90": round(float(np.percentile(a, 90)), 3),
        "worst": round(float(a.max()), 3),
    }


@click.command("photos")
@click.option("--json", "json_path", type=click.Path(path_type=Path), required=True)
@click.option("--seeds", type=int, default=20, show_default=True)
@click.option("--lines", type=int, default=4, show_default=True)
@click.option("--photos-per-line", type=int, default=10, show_default=True)
@click.option("--line-spacing-m", type=float, default=40.0, show_default=True)
@click.option("--interval-s", type=float, default=2.0, show_default=True)
@click.option("--speed-m-s", type=float, default=8.0, show_default=True)
@click.option("--sfm-noise-m", type=float, default=0.1, show_default=True)
def photos(
    json_path: Path,
    seeds: int,
    lines: int,
    photos_per_line: int,
    line_spacing_m: float,
    interval_s: float,
    speed_m_s: float,
    sfm_noise_m: float,
) -> None:
    """Photo sets with consumer GPS: robust fit against the trajectory fit, against truth."""
    start = time.perf_counter()
    runs = [
        run_seed(s, lines, photos_per_line, line_spacing_m, interval_s, speed_m_s, sfm_noise_m)
        for s in range(seeds)
    ]
    result: dict[str, Any] = {
        "gnss": GnssErrorModel.named("consumer").to_dict(),
        "options": {
            "seeds": seeds,
            "lines": lines,
            "photos_per_line": photos_per_line,
            "line_spacing_m": line_spacing_m,
            "interval_s": interval_s,
            "speed_m_s": speed_m_s,
            "sfm_noise_m": sfm_noise_m,
        },
        "note": "RMS error of the georeferenced camera centres against the true positions "
        "(m), the flight's GNSS bias included; SfM simulated (true centres + noise)",
    }
    for fit in ("robust", "similarity"):
        result[fit] = {
            "horizontal_rms_m": _summary([r[f"{fit}_h"] for r in runs]),
            "vertical_rms_m": _summary([r[f"{fit}_v"] for r in runs]),
            "horizontal_rms_beyond_bias_m": _summary([r[f"{fit}_h_beyond_bias"] for r in runs]),
            "vertical_rms_beyond_bias_m": _summary([r[f"{fit}_v_beyond_bias"] for r in runs]),
            "seconds_per_set": _summary([r[f"{fit}_seconds"] for r in runs]),
        }
    result["robust"]["outliers"] = {
        "planted": sum(r["planted"] for r in runs),
        "flagged": sum(r["flagged"] for r in runs),
        "flagged_and_planted": sum(r["flagged_planted"] for r in runs),
    }
    result["gnss_bias_h_m"] = _summary([r["gnss_bias_h"] for r in runs])
    result["seconds"] = round(time.perf_counter() - start, 3)
    result["runs"] = [
        {k: round(v, 4) if isinstance(v, float) else v for k, v in r.items()} for r in runs
    ]
    for fit in ("robust", "similarity"):
        h, v = result[fit]["horizontal_rms_m"], result[fit]["vertical_rms_m"]
        hb, vb = (
            result[fit]["horizontal_rms_beyond_bias_m"],
            result[fit]["vertical_rms_beyond_bias_m"],
        )
        click.echo(
            f"{fit:10s} horizontal RMS median {h['median']:.2f} p90 {h['p90']:.2f} worst "
            f"{h['worst']:.2f} m | vertical median {v['median']:.2f} p90 {v['p90']:.2f} "
            f"worst {v['worst']:.2f} m | beyond the GNSS bias: horizontal median "
            f"{hb['median']:.2f} p90 {hb['p90']:.2f} worst {hb['worst']:.2f}, vertical "
            f"median {vb['median']:.2f} p90 {vb['p90']:.2f} worst {vb['worst']:.2f} m"
        )
    o = result["robust"]["outliers"]
    click.echo(
        f"outliers: {o['flagged']} flagged, {o['planted']} planted, "
        f"{o['flagged_and_planted']} of the planted flagged; GNSS bias (horizontal) median "
        f"{result['gnss_bias_h_m']['median']:.2f} m; {seeds} seeds in {result['seconds']:.1f} s"
    )
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")

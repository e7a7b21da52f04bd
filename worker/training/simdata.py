"""Detection datasets from the survey simulator (worker/simulator, `simulate_scenario`).

`dataset_from_simulation` turns a simulator output (manifest.json) into a detection
dataset: training pairs (Step1, Stepk) as in the paper, their mask the simulator's
`mask_since_step1`. DSMs are either the reconstruction's DSMs of the simulated surveys
(pass `reconstructed`; the real thing) or, until the reconstruction exists, the truth
DSMs degraded ONCE per step by recon_noise.degrade (seeded per step), as if each survey
had been reconstructed once; pairs share their Step1 DSM, as the paper's pairs share the
Step1 reconstruction. Such datasets say `"interim": true`.

Regions (uint8 rasters, 1 inside): for paper-mounds, "mound-A" and "mound-B" are the
cells within `MOUND_ZONE_M` of a mound's centre and nearer to it than to the other
mound; the paper's test set is pair Step1-Step5 in mound-A (`test` in the manifest).

`no_change_pair` / `write_no_change_dataset`: pairs with nuisance only (vegetation
growth, the scenario's small surface changes), for training negatives and false-alarm
checks. `combine_datasets` lists the pairs of several datasets in one manifest.

This module imports the simulator lazily, so importing the training package does not
load it; the detection library (worker/pipeline) never depends on the simulator.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from rasterio.crs import CRS as RioCRS

from worker.pipeline.raster_io import write_geotiff
from worker.training.dataset import write_manifest
from worker.training.recon_noise import ReconstructionNoise, degrade

MOUND_ZONE_M = 6.0


def dataset_from_simulation(
    sim_manifest: Path,
    out_dir: Path,
    noise: ReconstructionNoise | None = None,
    noise_seed: int | None = None,
    reconstructed: dict[int, Path] | None = None,
    name: str | None = None,
) -> Path:
    """A detection dataset from a simulator output (`manifest.json`, slidewatch-sim/1).

    Pairs Step1 -> Stepk with the simulator's `mask_since_step1` (classes 1/2 -> 1).
    DSMs: `reconstructed[k]` when given (the reconstruction's DSM of step k: the real
    thing, dsm_source "reconstruction"), else the truth DSM degraded by recon_noise
    (interim). Regions: mound zones on paper-mounds, "all" otherwise. Test: the
    simulator's registration step and patterns.
    """
    import json
    import os

    import rasterio

    sim_manifest = Path(sim_manifest)
    sim = json.loads(sim_manifest.read_text())
    root = sim_manifest.parent
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    noise = noise or ReconstructionNoise()
    seed = int(sim.get("seed", 0))
    base_seed = seed * 1000 + 17 if noise_seed is None else noise_seed
    steps = sorted(sim["steps"], key=lambda s: s["index"])
    dsm_rel: dict[int, str] = {}
    transform = crs = None
    px = float(sim["grid"]["res_m"])
    for step in steps:
        k = int(step["index"])
        truth_path = root / step["truth"]["dsm"]
        if reconstructed and k in reconstructed:
            dsm_rel[k] = os.path.relpath(Path(reconstructed[k]).resolve(), out.resolve())
            continue
        with rasterio.open(truth_path) as src:
            truth = src.read(1, masked=True).astype(np.float32).filled(np.nan)
            transform, crs = src.transform, src.crs
        degraded = degrade(truth, px, np.random.default_rng(base_seed + k), noise)
        write_geotiff(out / "dsm" / f"step{k}.tif", degraded, transform, crs)
        dsm_rel[k] = f"dsm/step{k}.tif"
    pairs = []
    for step in steps[1:]:
        k = int(step["index"])
        with rasterio.open(root / step["truth"]["mask_since_step1"]) as src:
            classes = src.read(1)
            transform, crs = src.transform, src.crs
        mask = np.where(classes == 255, 255, (classes > 0).astype(np.uint8)).astype(np.uint8)
        pair_id = f"step1-step{k}"
        write_geotiff(out / "mask" / f"{pair_id}.tif", mask, transform, crs)
        pairs.append(
            {
                "id": pair_id,
                "pre": dsm_rel[1],
                "post": dsm_rel[k],
                "mask": f"mask/{pair_id}.tif",
                "truth_pre": os.path.relpath(root / steps[0]["truth"]["dsm"], out),
                "truth_post": os.path.relpath(root / step["truth"]["dsm"], out),
                "steps": [1, k],
            }
        )
    regions = {}
    shape = (int(sim["grid"]["height"]), int(sim["grid"]["width"]))
    mounds = sim.get("scene", {}).get("mounds")
    if mounds:
        west, north = float(sim["grid"]["west"]), float(sim["grid"]["north"])
        e0, n0 = float(sim["frame"]["origin_e"]), float(sim["frame"]["origin_n"])
        x = west - e0 + (np.arange(shape[1]) + 0.5) * px
        y = north - n0 - (np.arange(shape[0]) + 0.5) * px
        xx, yy = np.meshgrid(x, y)
        dist = np.stack(
            [np.hypot(xx - m["center_local"][0], yy - m["center_local"][1]) for m in mounds]
        )
        nearest = np.argmin(dist, axis=0)
        for i, m in enumerate(mounds):
            zone = ((nearest == i) & (dist[i] <= MOUND_ZONE_M)).astype(np.uint8)
            write_geotiff(out / "regions" / f"mound-{m['name']}.tif", zone, transform, crs)
            regions[f"mound-{m['name']}"] = f"regions/mound-{m['name']}.tif"
    else:
        write_geotiff(out / "regions" / "all.tif", np.ones(shape, np.uint8), transform, crs)
        regions["all"] = "regions/all.tif"
    registration = sim.get("registration") or []
    test_step = int(registration[0]["step"]) if registration else int(steps[-1]["index"])
    patterns = {r["pattern"]: list(r["shift_enu_m"]) for r in registration}
    if not patterns:
        from worker.simulator.registration import registration_patterns

        scale = float(sim.get("scenario_info", {}).get("registration_scale", 1.0))
        patterns = {k: list(v) for k, v in registration_patterns(scale).items()}
    interim = not reconstructed
    manifest = out / "dataset.json"
    write_manifest(
        manifest,
        {
            "name": (name or f"{sim['scenario']}-seed{seed}") + ("-interim" if interim else ""),
            "interim": interim,
            "dsm_source": (
                "simulator truth DSMs degraded by recon_noise (interim)"
                if interim
                else "slidewatch reconstruction of the simulated surveys"
            ),
            "description": (
                f"Simulator output {os.path.relpath(sim_manifest, out)} ({sim['scenario']}, "
                f"seed {seed}); masks: mask_since_step1 (depletion or deposition)."
            ),
            "simulation": os.path.relpath(sim_manifest, out),
            "scenario": sim["scenario"],
            "seed": seed,
            "noise_seed": base_seed if interim else None,
            "noise_model": noise.to_dict() if interim else None,
            "pixel_size_m": px,
            "registration_scale": float(
                sim.get("scenario_info", {}).get("registration_scale", 1.0)
            ),
            "crs": sim["crs"],
            "pairs": pairs,
            "regions": regions,
            "test": {
                "pair": f"step1-step{test_step}",
                "region": "mound-A" if "mound-A" in regions else "all",
                "patterns": patterns,
            },
        },
    )
    return manifest


def simulate_dataset(out_dir: Path, scenario: str, seed: int = 0) -> Path:
    """Run the simulator (truth only, no survey rendering) and make the interim dataset."""
    from worker.simulator import SimulationOptions, simulate_scenario

    out = Path(out_dir)
    sim = simulate_scenario(
        scenario, out / "simulation", SimulationOptions(seed=seed, survey="none", write_ortho=False)
    )
    return dataset_from_simulation(sim.path, out)


def no_change_pair(
    scenario: str = "paper-mounds",
    seed: int = 1,
    noise: ReconstructionNoise | None = None,
    with_truth: bool = False,
) -> tuple:
    """A pair with no landslide: Step1 and Step2 with nuisance only (the scenario's own
    nuisance, plus, on paper-mounds, growth of the model trees and shrubs by 5 cm in
    height and 1-2 cm in crown radius, one tenth of a season's growth of real trees).
    Both truth DSMs are degraded independently. Returns (pre, post, transform, crs, px).
    """
    from worker.simulator.evolution import advance
    from worker.simulator.georef import SceneFrame
    from worker.simulator.scenario import get_scenario
    from worker.simulator.texture import MODEL_TREE, SHRUB
    from worker.simulator.vegetation import grow

    spec = get_scenario(scenario)
    rng = np.random.default_rng(seed)
    scene = spec.build(rng)
    frame = SceneFrame.at_lonlat(spec.lon, spec.lat, spec.crs)
    before, _ = scene.compose()

    def nuisance(s, protect, r):
        info = spec.nuisance(s, protect, r)
        if scenario == "paper-mounds":
            s.trees = grow(
                s.trees,
                r,
                height_m={MODEL_TREE: 0.05, SHRUB: 0.05},
                crown_m={MODEL_TREE: 0.01, SHRUB: 0.02},
            )
            info["model_tree_growth_m"] = 0.05
        return info

    scene, _ = advance(scene, [], nuisance, rng, dsm_before=before)
    after, _ = scene.compose()
    px = float(scene.grid.res)
    noise = noise or ReconstructionNoise()
    pre = degrade(before, px, np.random.default_rng([seed, 91]), noise)
    post = degrade(after, px, np.random.default_rng([seed, 92]), noise)
    if with_truth:
        return pre, post, scene.grid.transform(frame), frame.crs, px, before, after
    return pre, post, scene.grid.transform(frame), frame.crs, px


def random_slides_pair(scenario: str, seed: int, n_slides: int = 5) -> tuple:
    """Training slides that are not the scenario's: `n_slides` random slides (random
    place, size, depth, runout) on a fresh realisation of the scenario's terrain, with its
    nuisance. Hillslope only (worker/simulator/random_slides.py); trees on moving ground
    fall, as in the scenario. Returns
    (pre, post, mask, transform, crs, px), both DSMs degraded.
    """
    from worker.simulator.evolution import advance
    from worker.simulator.georef import SceneFrame
    from worker.simulator.random_slides import random_hillslope_slides
    from worker.simulator.scenario import get_scenario

    if scenario != "hillslope":
        raise ValueError("random training slides are defined for the hillslope only")
    spec = get_scenario(scenario)
    rng = np.random.default_rng([seed, 7])
    scene = spec.build(np.random.default_rng(seed))
    frame = SceneFrame.at_lonlat(spec.lon, spec.lat, spec.crs)
    before, _ = scene.compose()
    slides = random_hillslope_slides(scene, rng, n_slides)
    while True:
        try:
            scene, change = advance(scene, slides, spec.nuisance, rng, dsm_before=before)
            break
        except ValueError as exc:  # a slide that does not fit once the others moved
            bad = [sl for sl in slides if repr(sl.name) in str(exc)]
            if not bad:
                raise
            slides = [sl for sl in slides if sl not in bad]
    after, _ = scene.compose()
    px = float(scene.grid.res)
    noise = ReconstructionNoise()
    pre = degrade(before, px, np.random.default_rng([seed, 93]), noise)
    post = degrade(after, px, np.random.default_rng([seed, 94]), noise)
    mask = (change.mask > 0).astype(np.uint8)
    return pre, post, mask, scene.grid.transform(frame), frame.crs, px, before, after


def write_random_slides_dataset(out_dir: Path, scenario: str, seed: int, n_slides: int = 5):
    """`random_slides_pair` written as a one-pair dataset."""
    pre, post, mask, transform, crs, px, before, after = random_slides_pair(
        scenario, seed, n_slides
    )
    out = Path(out_dir)
    rio_crs = RioCRS.from_user_input(crs)
    write_geotiff(out / "dsm" / "pre.tif", pre, transform, rio_crs)
    write_geotiff(out / "dsm" / "post.tif", post, transform, rio_crs)
    write_geotiff(out / "truth" / "pre.tif", before, transform, rio_crs)
    write_geotiff(out / "truth" / "post.tif", after, transform, rio_crs)
    write_geotiff(out / "mask" / "slides.tif", mask, transform, rio_crs)
    manifest = out / "dataset.json"
    write_manifest(
        manifest,
        {
            "name": f"{scenario}-seed{seed}-random-slides-interim",
            "interim": True,
            "dsm_source": "simulator truth DSMs degraded by recon_noise (interim)",
            "description": (
                f"{n_slides} random training slides on {scenario} (seed {seed}), away from "
                "the scenario's own slides; both DSMs degraded."
            ),
            "scenario": scenario,
            "seed": seed,
            "pixel_size_m": px,
            "pairs": [
                {
                    "id": "random-slides",
                    "pre": "dsm/pre.tif",
                    "post": "dsm/post.tif",
                    "mask": "mask/slides.tif",
                    "truth_pre": "truth/pre.tif",
                    "truth_post": "truth/post.tif",
                    "steps": [1, 2],
                }
            ],
        },
    )
    return manifest


def write_no_change_dataset(out_dir: Path, scenario: str, seed: int) -> Path:
    """A one-pair dataset: `no_change_pair` written as GeoTIFFs, its mask all 0."""
    pre, post, transform, crs, px, before, after = no_change_pair(scenario, seed, with_truth=True)
    out = Path(out_dir)
    rio_crs = RioCRS.from_user_input(crs)
    write_geotiff(out / "dsm" / "pre.tif", pre, transform, rio_crs)
    write_geotiff(out / "dsm" / "post.tif", post, transform, rio_crs)
    write_geotiff(out / "truth" / "pre.tif", before, transform, rio_crs)
    write_geotiff(out / "truth" / "post.tif", after, transform, rio_crs)
    write_geotiff(out / "mask" / "none.tif", np.zeros(pre.shape, np.uint8), transform, rio_crs)
    manifest = out / "dataset.json"
    write_manifest(
        manifest,
        {
            "name": f"{scenario}-seed{seed}-no-change-interim",
            "interim": True,
            "dsm_source": "simulator truth DSMs degraded by recon_noise (interim)",
            "description": (
                f"No landslide: {scenario} (seed {seed}) Step1 and Step2 with nuisance only "
                "(vegetation growth and small surface changes), both degraded."
            ),
            "scenario": scenario,
            "seed": seed,
            "pixel_size_m": px,
            "pairs": [
                {
                    "id": "no-change",
                    "pre": "dsm/pre.tif",
                    "post": "dsm/post.tif",
                    "mask": "mask/none.tif",
                    "truth_pre": "truth/pre.tif",
                    "truth_post": "truth/post.tif",
                    "steps": [1, 2],
                }
            ],
        },
    )
    return manifest


def combine_datasets(
    out_path: Path, name: str, manifests: list[Path], augmentation: list[Path] | None = None
) -> Path:
    """One manifest listing the pairs of several (ids prefixed by each dataset's name);
    regions and test come from the first. Paths stay relative, so keep the folders.
    `dsm_source` says where each part's DSMs come from; `interim` is true when any part
    is interim, and `interim_parts` names those parts. `augmentation` parts are added to
    training on purpose (e.g. other kinds of DSM noise) and listed in
    `augmentation_parts`; they do not make the set interim."""
    import json
    import os

    out_path = Path(out_path)
    combined: dict[str, Any] = {"name": name, "pairs": [], "regions": {}, "sources": []}
    by_source: dict[str, list[str]] = {}
    interim_parts: list[str] = []
    augmentation = list(augmentation or [])
    augmentation_parts: list[str] = []
    for k, manifest in enumerate([*manifests, *augmentation]):
        raw = json.loads(Path(manifest).read_text())
        rel = Path(os.path.relpath(Path(manifest).parent, out_path.parent))
        if k >= len(manifests):
            augmentation_parts.append(raw["name"])
        elif raw.get("interim"):
            interim_parts.append(raw["name"])
        by_source.setdefault(raw.get("dsm_source") or "unknown", []).append(raw["name"])
        combined["sources"].append(str(rel / Path(manifest).name))
        for pair in raw["pairs"]:
            entry = dict(pair)
            entry["id"] = pair["id"] if k == 0 else f"{raw['name']}/{pair['id']}"
            for key in ("pre", "post", "mask", "truth_pre", "truth_post"):
                if key in entry:
                    entry[key] = str(rel / entry[key])
            combined["pairs"].append(entry)
        if k == 0:
            combined["regions"] = {r: str(rel / v) for r, v in raw.get("regions", {}).items()}
            for key in ("test", "registration_scale", "scenario", "seed", "noise_model"):
                if key in raw:
                    combined[key] = raw[key]
    combined["dsm_source"] = "; ".join(
        f"{source} ({', '.join(names)})" for source, names in by_source.items()
    )
    combined["interim"] = bool(interim_parts)
    combined["interim_parts"] = interim_parts
    combined["augmentation_parts"] = augmentation_parts
    combined["description"] = "Pairs of: " + ", ".join(combined["sources"])
    write_manifest(out_path, combined)
    return out_path

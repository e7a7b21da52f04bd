"""Detection datasets whose DSMs are slidewatch's own reconstructions of simulated flights.

The paper trains and tests its CNN on DSO DSMs of real flights, "georeferenced manually,
so that they contained no registration error". Here each simulated survey (video + DJI
SRT log, rendered by worker/simulator) goes through the reconstruction pipeline, the same
as `slidewatch reconstruct` (frames, visual SLAM, trajectory georeferencing, DSM export
with inpainting), and the DSM is then put onto the scenario's truth grid and
co-registered onto that step's truth DSM (Nuth & Kaab shift and tilt on the whole grid:
the hand georeferencing). What is left is the reconstruction's own error: noise, holes
filled by inpainting, smoothing of sharp edges, local drift. Labels are the simulator's
masks.

Every step is cached in `work_dir`: a step whose registered DSM exists is not redone,
so an interrupted run resumes where it stopped.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from worker.pipeline.atomic import write_text_atomic
from worker.pipeline.coregister import CoregisterOptions, CoregisterResult, coregister
from worker.pipeline.raster_io import read_elevation, warp_elevation, write_geotiff
from worker.pipeline.reconstruction import (
    ReconstructionInputs,
    ReconstructionOptions,
    reconstruct_survey,
)

if TYPE_CHECKING:
    from worker.simulator import SimulationOptions

REGISTERED = "registered.tif"
REGISTRATION = "registration.json"
# A reconstruction further than this from its truth after registration has failed (e.g.
# a short straight pass rolled about its track): it would teach false changes.
MAX_NMAD_PX = 5.0


@dataclass(frozen=True)
class RegistrationToTruth:
    """What putting one reconstructed DSM onto its truth did, and what error remains."""

    shift_enu_m: tuple[float, float, float]
    nmad_before_m: float
    nmad_after_m: float
    valid_fraction: float  # cells of the truth grid with a reconstructed elevation
    # The correction itself (shift, tilt), to move the DSM's own cells onto the truth.
    correction: CoregisterResult | None = field(default=None, compare=False, repr=False)

    def check(self, pixel_size_m: float, what: str, max_nmad_px: float = MAX_NMAD_PX) -> None:
        """Raise ValueError when the registered DSM is too far from its truth to be used."""
        nmad_px = self.nmad_after_m / pixel_size_m
        if not nmad_px <= max_nmad_px:
            raise ValueError(
                f"{what}: the reconstructed DSM differs from its truth by an NMAD of "
                f"{self.nmad_after_m:.3f} m ({nmad_px:.1f} pixels) after registration, more "
                f"than {max_nmad_px:g} pixels: the reconstruction failed and is not used"
            )

    def to_dict(self) -> dict[str, Any]:
        return {
            "shift_enu_m": [round(v, 4) for v in self.shift_enu_m],
            "nmad_before_m": round(self.nmad_before_m, 4),
            "nmad_after_m": round(self.nmad_after_m, 4),
            "valid_fraction": round(self.valid_fraction, 4),
        }


def register_to_truth(dsm: Path, truth: Path, out: Path) -> RegistrationToTruth:
    """Resample `dsm` onto the grid of `truth` and co-register it there (the paper's
    manual georeferencing); write the result to `out` (GeoTIFF on the truth grid)."""
    source, profile = read_elevation(dsm)
    _, truth_profile = read_elevation(truth)
    shape = (int(truth_profile["height"]), int(truth_profile["width"]))
    warped = warp_elevation(
        source,
        profile["transform"],
        profile["crs"],
        truth_profile["transform"],
        truth_profile["crs"],
        shape,
    )
    with tempfile.TemporaryDirectory(dir=Path(out).parent) as tmp:
        warped_path = Path(tmp) / "warped.tif"
        write_geotiff(warped_path, warped, truth_profile["transform"], truth_profile["crs"])
        # The whole survey is one epoch with its truth: nothing moved, so every cell is
        # stable terrain except the reconstruction's blunders, which the iterations drop.
        result = coregister(truth, warped_path, out, CoregisterOptions(max_abs_change_m=2.0))
    return RegistrationToTruth(
        shift_enu_m=(result.shift_east_m, result.shift_north_m, result.shift_up_m),
        nmad_before_m=result.nmad_before_m,
        nmad_after_m=result.nmad_after_m,
        valid_fraction=float(np.count_nonzero(np.isfinite(warped)) / warped.size),
        correction=result,
    )


def reconstruct_simulation(
    sim_manifest: Path,
    work_dir: Path,
    options: ReconstructionOptions | None = None,
    log: Callable[[str], None] = print,
) -> dict[int, Path]:
    """Reconstruct the (first) video survey of every step of a simulation and register
    each DSM onto its truth. Returns {step index: registered DSM}; cached per step: the
    registered DSM is moved into place last, after its figures, so a step that has it is
    complete."""
    from worker.simulator.manifest import Manifest

    sim = Manifest.load(Path(sim_manifest))
    work = Path(work_dir)
    registered: dict[int, Path] = {}
    for step in sim.steps:
        k = int(step["index"])
        folder = work / f"step{k}"
        out = folder / REGISTERED
        if not out.exists():
            survey = sim.survey(k)
            if not survey.get("video") or not survey.get("srt"):
                raise ValueError(f"step {k} of {sim.path} has no video survey with an SRT log")
            log(f"reconstructing step {k} ({survey['video']}) ...")
            result = reconstruct_survey(
                ReconstructionInputs(
                    video=str(sim.resolve(survey["video"])), log=str(sim.resolve(survey["srt"]))
                ),
                folder / "reconstruction",
                options or ReconstructionOptions(method="slam"),
            )
            pending = folder / f"pending-{REGISTERED}"
            registration = register_to_truth(result.dsm_path, sim.truth(k), pending)
            try:
                registration.check(float(sim.data["grid"]["res_m"]), f"step {k} of {sim.path}")
            except ValueError:
                pending.unlink()
                raise
            summary = {**result.summary(), "registration_to_truth": registration.to_dict()}
            write_text_atomic(folder / REGISTRATION, json.dumps(summary, indent=1))
            os.replace(pending, out)
            log(f"step {k}: {json.dumps(summary)}")
        registered[k] = out
    return registered


def survey_simulation(
    seed: int = 0, steps: int | None = None, slides: bool = True, random_slides: int = 0
) -> SimulationOptions:
    """Simulation options of a dataset's surveys: video with DJI SRT, RTK GNSS. The
    georeferencing error is removed by the registration to the truth anyway (as the paper
    georeferenced by hand); RTK keeps it small to begin with."""
    from worker.simulator import SimulationOptions

    return SimulationOptions(
        seed=seed,
        steps=steps,
        slides=slides,
        random_slides=random_slides,
        survey="video",
        gnss="rtk",
    )


def reconstructed_dataset(
    out_dir: Path,
    scenario: str,
    simulation: SimulationOptions | None = None,
    options: ReconstructionOptions | None = None,
    log: Callable[[str], None] = print,
) -> Path:
    """Simulate `scenario` (`simulation`, default `survey_simulation()`), reconstruct
    every step's survey, and write the detection dataset `out_dir/dataset.json` (pairs
    Step1 -> Stepk) on those DSMs. With `slides=False` it is a no-change dataset."""
    from worker.simulator import simulate_scenario
    from worker.training.simdata import dataset_from_simulation

    simulation = simulation or survey_simulation()
    out = Path(out_dir)
    sim_manifest = out / "simulation" / "manifest.json"
    if not sim_manifest.exists():
        log(f"simulating {scenario} (seed {simulation.seed}) with video surveys ...")
        simulate_scenario(scenario, out / "simulation", simulation)
    registered = reconstruct_simulation(sim_manifest, out / "reconstruction", options, log)
    name = f"{scenario}-seed{simulation.seed}" + (
        "-random-slides"
        if simulation.random_slides
        else ("" if simulation.slides else "-no-change")
    )
    return dataset_from_simulation(sim_manifest, out, reconstructed=registered, name=name)


def default_training_set(out_dir: Path, log: Callable[[str], None] = print) -> Path:
    """The training data of the shipped SlideNet, rebuilt from the simulator (seeded),
    every survey reconstructed; returns the combined manifest `training-set.json`:

    - paper-mounds seed 0, every step reconstructed (its test region is held out at
      training);
    - no-change surveys (vegetation growth and nuisance only) of paper-mounds and of the
      hillslope, seed 2, reconstructed;
    - hillslope surveys before and after 5 random slides (seeds 3 and 4), placed away from
      the scenario's own slides, which are test data (worker/simulator/random_slides.py),
      reconstructed;
    - augmentation, so that DSMs from other software (with other artefacts: outlier blobs,
      blunders, grey levels) do not raise false alarms: the truth DSMs of paper-mounds
      seed 6, of a paper-mounds no-change pair (seed 2) and of the hillslope random
      slides (seeds 3 and 4) degraded by recon_noise.
    """
    from worker.training.simdata import (
        combine_datasets,
        simulate_dataset,
        write_no_change_dataset,
        write_random_slides_dataset,
    )

    out = Path(out_dir)
    parts = []
    for folder_name, scenario, simulation in (
        ("paper-mounds-seed0", "paper-mounds", survey_simulation(0)),
        ("paper-mounds-seed2-no-change", "paper-mounds", survey_simulation(2, 2, slides=False)),
        ("hillslope-seed2-no-change", "hillslope", survey_simulation(2, 2, slides=False)),
        ("hillslope-seed3-random-slides", "hillslope", survey_simulation(3, 2, random_slides=5)),
        ("hillslope-seed4-random-slides", "hillslope", survey_simulation(4, 2, random_slides=5)),
    ):
        manifest = out / folder_name / "dataset.json"
        if not manifest.exists():
            reconstructed_dataset(manifest.parent, scenario, simulation, log=log)
        parts.append(manifest)
    augmentation = []
    for folder_name, make in (
        ("paper-mounds-seed6-interim", lambda f: simulate_dataset(f, "paper-mounds", 6)),
        (
            "paper-mounds-seed2-no-change-interim",
            lambda f: write_no_change_dataset(f, "paper-mounds", 2),
        ),
        *(
            (
                f"hillslope-seed{seed}-random-slides-interim",
                lambda f, seed=seed: write_random_slides_dataset(f, "hillslope", seed, 5),
            )
            for seed in (3, 4)
        ),
    ):
        manifest = out / folder_name / "dataset.json"
        if not manifest.exists():
            make(manifest.parent)
        augmentation.append(manifest)
    return combine_datasets(
        out / "training-set.json",
        "paper-mounds-seed0+no-change+hillslope-random-slides",
        parts,
        augmentation,
    )

"""The two scenarios: where they are, how their slides progress, what else changes, and
how they are flown.

- ``paper-mounds``: the paper's field near Tsukuba (UTM 54N, EPSG:32654), DSM at 2 cm.
  Each mound collapses progressively: Step1 intact, then one slide per mound per step
  with a growing source (longer, wider, a gentler failure plane) until the last step
  (Step6 by default) is fully collapsed. Sand: head and flank scarps at the angle of
  repose (33/31 deg), the moved sand comes to rest at the foot as a fan at 24 deg.
  Nuisance: footprints of the people who worked on the mounds, a few millimetres of
  wind-blown sand, lawn growth. Flown as a lawnmower at 7 m with 60 % side overlap (the
  paper's survey) or the paper's 3-D trajectory (7-20 m).
- ``hillslope``: a forested slope in the mountains north of Nikko (EPSG:32654), DSM at
  20 cm. Step2: a deep-seated slide (10-17 m deep at the head) whose debris crosses the
  road into the valley, and a small bank slump; Step3 (if asked): retrogression of the
  head scarp. Nuisance: trees, shrubs and grass grow, a meadow is mown, rain washes a
  few centimetres of soil. Flown along the contours (two 200 m lines) at 100 m
  above the terrain at 14 m/s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from worker.simulator.flight_plan import FlightPlan
from worker.simulator.landslide import SlideSpec
from worker.simulator.terrain import (
    PAPER_FIELD_HALF,
    PAPER_MOUNDS,
    Scene,
    hillslope_scene,
    paper_mounds_scene,
    stream_y,
)
from worker.simulator.texture import BROADLEAF, CONIFER, MODEL_TREE, SHRUB, Material, fbm
from worker.simulator.vegetation import Trees, grow

SCENARIOS = ("paper-mounds", "hillslope")


@dataclass(frozen=True)
class ScenarioSpec:
    name: str
    description: str
    lon: float
    lat: float
    crs: str
    res: float
    default_steps: int
    registration_scale: float
    home_xy: tuple[float, float]
    local_utc_offset_h: float = 9.0

    def build(self, rng: np.random.Generator) -> Scene:
        if self.name == "paper-mounds":
            return paper_mounds_scene(rng, res=self.res, size_m=36.0, base_z=25.0)
        return hillslope_scene(rng, res=self.res)

    def slides(self, step: int, n_steps: int) -> list[SlideSpec]:
        """Slides between step-1 and `step` (steps count from 1)."""
        if step < 2:
            return []
        if self.name == "paper-mounds":
            return _paper_slides(step, n_steps)
        return _hill_slides(step)

    def nuisance(self, scene: Scene, protect: np.ndarray, rng: np.random.Generator) -> dict:
        if self.name == "paper-mounds":
            return _paper_nuisance(scene, protect, rng)
        return _hill_nuisance(scene, protect, rng)

    def flight_plan(
        self,
        kind: str | None = None,
        altitude_m: float | None = None,
        speed_m_s: float | None = None,
        duration_s: float | None = None,
    ) -> FlightPlan:
        if self.name == "paper-mounds":
            kind = kind or "lawnmower"
            if kind not in ("lawnmower", "paper-3d"):
                raise ValueError(f"unknown flight {kind!r}: use lawnmower or paper-3d")
            side = 2 * PAPER_FIELD_HALF + 2.0
            return FlightPlan(
                kind=kind,
                center_xy=(0.0, 0.0),
                length_m=side,
                width_m=side,
                line_azimuth_deg=0.0,
                altitude_m=altitude_m or 7.0,
                altitude_max_m=20.0 if kind == "paper-3d" else None,
                side_overlap=0.6,
                speed_m_s=speed_m_s or 4.0,
                duration_s=duration_s,
            )
        kind = kind or "lawnmower"
        if kind != "lawnmower":
            raise ValueError("the hillslope is flown as a lawnmower")
        return FlightPlan(
            kind="lawnmower",
            center_xy=(-25.0, -20.0),
            length_m=200.0,
            width_m=190.0,
            line_azimuth_deg=90.0,
            altitude_m=altitude_m or 100.0,
            side_overlap=0.6,
            speed_m_s=speed_m_s or 14.0,
            duration_s=duration_s,
            terrain_following=True,
        )

    def registration_step(self, n_steps: int) -> int:
        """The step whose DSM gets the registration patterns (the paper used Step5)."""
        return min(5, n_steps) if self.name == "paper-mounds" else n_steps

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "description": self.description,
            "dsm_resolution_m": self.res,
            "registration_scale": self.registration_scale,
            "local_utc_offset_h": self.local_utc_offset_h,
        }


def get_scenario(name: str) -> ScenarioSpec:
    if name == "paper-mounds":
        return ScenarioSpec(
            name=name,
            description=(
                "Replica of the paper's experiment: ~20 m x 20 m sand field with mounds A "
                "and B (~1.5 m), progressive collapse per mound, 2 cm DSM"
            ),
            lon=140.1045,
            lat=36.0586,
            crs="EPSG:32654",
            res=0.02,
            default_steps=6,
            registration_scale=1.0,
            home_xy=(-11.5, -11.0),
        )
    if name == "hillslope":
        return ScenarioSpec(
            name=name,
            description=(
                "Real-scale forested hillslope (400 m x 300 m) with gullies and a valley, "
                "a deep-seated landslide into the valley, 20 cm DSM"
            ),
            lon=139.5480,
            lat=36.8030,
            crs="EPSG:32654",
            res=0.2,
            default_steps=2,
            registration_scale=10.0,
            home_xy=(-150.0, float(stream_y(-150.0)) + 22.0),
        )
    raise ValueError(f"unknown scenario {name!r}: use one of {', '.join(SCENARIOS)}")


def _paper_slides(step: int, n_steps: int) -> list[SlideSpec]:
    p = (step - 1) / max(n_steps - 1, 1)  # progress 0 < p <= 1
    out = []
    for m in PAPER_MOUNDS:
        az = m.collapse_azimuth_deg
        r_dir = m.radius_towards(az)
        r_perp = m.radius_towards(az + 90.0)
        d = np.array([np.sin(np.radians(az)), np.cos(np.radians(az))])
        # The rupture surface daylights at the foot; as the collapse progresses it
        # flattens and its head retreats past the summit.
        toe = np.asarray(m.center) + 1.0 * r_dir * d
        out.append(
            SlideSpec(
                name=f"{m.name}-step{step}",
                label=f"mound {m.name}",
                toe_xy=(float(toe[0]), float(toe[1])),
                azimuth_deg=az,
                length_m=r_dir * (0.5 + 0.7 * p),
                width_m=r_perp * (1.0 + 0.5 * p),
                failure_angle_deg=22.0 - 19.0 * p,
                head_angle_deg=33.0,
                flank_angle_deg=31.0,
                runout_m=r_dir * (0.05 + 0.25 * p),
                deposit_angle_deg=24.0,
                deposit_spread=0.5,
                deposit_elongation=1.1,
                roughness=0.04,
            )
        )
    return out


def _hill_slides(step: int) -> list[SlideSpec]:
    if step == 2:
        toe_x = 25.0
        return [
            SlideSpec(
                name="main-step2",
                label="deep-seated slide",
                toe_xy=(toe_x, float(stream_y(toe_x)) + 75.0),
                azimuth_deg=182.0,
                length_m=65.0,
                width_m=50.0,
                failure_angle_deg=21.0,
                head_angle_deg=55.0,
                flank_angle_deg=45.0,
                runout_m=85.0,
                deposit_angle_deg=5.0,
                deposit_spread=0.8,
                deposit_elongation=0.8,
                roughness=0.05,
            ),
            SlideSpec(
                name="slump-step2",
                label="bank slump",
                toe_xy=(-95.0, float(stream_y(-95.0)) + 95.0),
                azimuth_deg=175.0,
                length_m=22.0,
                width_m=18.0,
                failure_angle_deg=24.0,
                head_angle_deg=50.0,
                flank_angle_deg=45.0,
                runout_m=8.0,
                deposit_angle_deg=40.0,
                deposit_spread=0.6,
                roughness=0.05,
            ),
        ]
    if step == 3:
        toe_x = 25.0
        return [
            SlideSpec(
                name="retrogression-step3",
                label="retrogression of the head scarp",
                toe_xy=(toe_x, float(stream_y(toe_x)) + 132.0),
                azimuth_deg=182.0,
                length_m=30.0,
                width_m=40.0,
                failure_angle_deg=24.0,
                head_angle_deg=55.0,
                flank_angle_deg=45.0,
                runout_m=20.0,
                deposit_angle_deg=30.0,
                deposit_spread=0.7,
                roughness=0.05,
            )
        ]
    return []


def _paper_nuisance(scene: Scene, protect: np.ndarray, rng: np.random.Generator) -> dict:
    grid = scene.grid
    free = ~protect
    cells = 1.0 / grid.res
    # Wind-blown sand: +-2 mm smooth changes on the sand.
    sand = scene.sand_like & free
    wind = 0.002 * fbm(grid.shape, rng, [0.4 * cells, 0.15 * cells], [0.7, 0.3])
    scene.ground[sand] += wind[sand]
    # Footprints (1.5 cm deep) on paths from the field edge to the mounds.
    n_prints = 0
    for m in PAPER_MOUNDS:
        start = np.array([rng.uniform(-9, 9), -PAPER_FIELD_HALF + 0.5])
        end = np.asarray(m.center) + rng.normal(0, 1.0, 2)
        n = int(np.linalg.norm(end - start) / 0.35)
        heading = np.arctan2(end[0] - start[0], end[1] - start[1])
        for i in range(n):
            f = i / max(n - 1, 1)
            p = start + f * (end - start)
            side = 0.12 if i % 2 == 0 else -0.12
            px = p[0] + side * np.cos(heading) + rng.normal(0, 0.03)
            py = p[1] - side * np.sin(heading) + rng.normal(0, 0.03)
            n_prints += _footprint(scene, free, px, py, heading, 0.015)
    # Lawn growth: 1-2 cm.
    grass = (scene.material == Material.GRASS) & free
    growth = np.clip(0.015 + 0.004 * fbm(grid.shape, rng, [0.5 * cells]), 0, None)
    scene.surface[grass] += growth[grass].astype(np.float32)
    return {
        "wind_blown_sand_m": 0.002,
        "footprints": n_prints,
        "footprint_depth_m": 0.015,
        "lawn_growth_m": 0.015,
    }


def _footprint(scene: Scene, free: np.ndarray, x: float, y: float, heading: float, depth: float):
    g = scene.grid
    rows, cols = g.window(x - 0.2, y - 0.2, x + 0.2, y + 0.2)
    if rows.stop <= rows.start or cols.stop <= cols.start:
        return 0
    sub = g.sub(rows, cols)
    xs, ys = sub.mesh()
    a = (xs - x) * np.sin(heading) + (ys - y) * np.cos(heading)
    b = (xs - x) * np.cos(heading) - (ys - y) * np.sin(heading)
    q = (a / 0.14) ** 2 + (b / 0.055) ** 2
    dent = -depth * np.sqrt(np.clip(1.0 - q, 0.0, None))
    ok = free[rows, cols] & scene.sand_like[rows, cols]
    scene.ground[rows, cols] += np.where(ok, dent, 0.0)
    return 1


def _hill_nuisance(scene: Scene, protect: np.ndarray, rng: np.random.Generator) -> dict:
    grid = scene.grid
    free = ~protect
    cells = 1.0 / grid.res
    trees = scene.trees
    # Growth (standing plants outside the slides only).
    col, row = grid.col_row(trees.x, trees.y)
    ri = np.clip(np.rint(row).astype(int), 0, grid.height - 1)
    ci = np.clip(np.rint(col).astype(int), 0, grid.width - 1)
    standing = free[ri, ci]
    grown = grow(
        trees.select(standing),
        rng,
        height_m={CONIFER: 0.25, BROADLEAF: 0.2, SHRUB: 0.1, MODEL_TREE: 0.0},
        crown_m={CONIFER: 0.05, BROADLEAF: 0.08, SHRUB: 0.05},
    )
    scene.trees = Trees.concat([grown, trees.select(~standing)])
    # Grass grows 8 cm; one meadow patch is mown to 5 cm.
    grass = (scene.material == Material.GRASS) & free
    scene.surface[grass] += np.float32(0.08)
    x, y = grid.mesh()
    mown = grass & (np.abs(x - 120.0) < 30.0) & (np.abs(y - (stream_y(x) + 12.0)) < 7.0)
    scene.surface[mown] = 0.05
    # Rain wash: +-2 cm smooth soil changes.
    wash = 0.02 * fbm(grid.shape, rng, [8 * cells, 2 * cells], [0.6, 0.4])
    scene.ground[free] += wash[free]
    return {
        "tree_growth_m": {"conifer": 0.25, "broadleaf": 0.2, "shrub": 0.1},
        "grass_growth_m": 0.08,
        "mown_area_m2": round(float(mown.sum() * grid.cell_area), 1),
        "rain_wash_m": 0.02,
    }

"""The post orthophoto drawn moved the way the co-registration moved its DSM: shift and
rotation about the comparison's grid centre, pixel for pixel."""

import dataclasses
import hashlib
import io
import math
import shutil
from datetime import UTC, datetime
from pathlib import Path

import morecantile
import numpy as np
import pytest
import rasterio
from fastapi import FastAPI
from fastapi.testclient import TestClient
from PIL import Image
from pyproj import Transformer
from rasterio.crs import CRS
from rasterio.enums import ColorInterp
from rasterio.transform import from_origin

from backend.db.models import (
    Comparison,
    JobState,
    Product,
    StoredFile,
    Survey,
    SurveyKind,
    SurveyStatus,
)
from backend.services.post_motion import PostMotion, motion_from_summary, moved_image
from tests.monitoring_helpers import token_for
from worker.pipeline.coregister import CoregisterResult

TMS = morecantile.tms.get("WebMercatorQuad")
UTM = "EPSG:32632"
# A 100 m orthophoto at 0.25 m in UTM zone 32 (the Alps), its north-west corner here.
WEST, NORTH, PIXEL, SIDE = 500_000.0, 5_100_000.0, 0.25, 400
MOTION = PostMotion(
    shift_east_m=2.0,
    shift_north_m=-1.5,
    rotation_deg=3.0,
    centre_east_m=WEST + 40.0,  # the grid centre need not be the raster's
    centre_north_m=NORTH - 55.0,
    crs=UTM,
)


def pattern(east: np.ndarray, north: np.ndarray) -> np.ndarray:
    """The ground's colours: smooth waves (12-20 m long), so that any misplacement of
    a metre shows as tens of grey levels while resampling costs under one."""
    x, y = east - WEST, north - NORTH
    return np.stack(
        [
            128 + 100 * np.sin(2 * np.pi * x / 14.0),
            128 + 100 * np.sin(2 * np.pi * y / 17.0),
            128 + 80 * np.sin(2 * np.pi * (x + y) / 20.0),
        ]
    )


@pytest.fixture(scope="module")
def orthophoto(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("ortho") / "orthophoto.tif"
    centres = WEST + (np.arange(SIDE) + 0.5) * PIXEL, NORTH - (np.arange(SIDE) + 0.5) * PIXEL
    east, north = np.meshgrid(*centres)
    rgb = np.clip(np.rint(pattern(east, north)), 0, 255).astype(np.uint8)
    alpha = np.full((1, SIDE, SIDE), 255, dtype=np.uint8)
    profile = {
        "driver": "GTiff",
        "width": SIDE,
        "height": SIDE,
        "count": 4,
        "dtype": "uint8",
        "crs": UTM,
        "transform": from_origin(WEST, NORTH, PIXEL, PIXEL),
        "photometric": "RGB",
    }
    with rasterio.open(path, "w", **profile) as dst:
        # Set before the pixels are written, as the orthophoto stage does: GDAL records
        # the alpha band's meaning in the header it writes first.
        dst.colorinterp = [ColorInterp.red, ColorInterp.green, ColorInterp.blue, ColorInterp.alpha]
        dst.write(np.concatenate([rgb, alpha]))
    return path


def tile_over(east: float, north: float, zoom: int) -> morecantile.Tile:
    lon, lat = Transformer.from_crs(UTM, "EPSG:4326", always_xy=True).transform(east, north)
    return TMS.tile(lon, lat, zoom)


def bounds_of(tile: morecantile.Tile) -> tuple[float, float, float, float]:
    """The tile's bounds in Web Mercator metres."""
    return tuple(TMS.xy_bounds(tile))  # type: ignore[return-value]


def expected_colours(bounds: tuple[float, float, float, float], motion: PostMotion) -> np.ndarray:
    """What the moved orthophoto shows at each pixel centre of the tile, from the pattern
    itself: the pixel's place in UTM, taken back through the motion by its own matrix."""
    left, bottom, right, top = bounds
    size = 256
    x = left + (np.arange(size) + 0.5) * (right - left) / size
    y = top - (np.arange(size) + 0.5) * (top - bottom) / size
    mx, my = np.meshgrid(x, y)
    east, north = Transformer.from_crs("EPSG:3857", UTM, always_xy=True).transform(mx, my)
    theta = math.radians(motion.rotation_deg)
    inverse = np.array([[math.cos(theta), math.sin(theta)], [-math.sin(theta), math.cos(theta)]])
    u = east - motion.shift_east_m - motion.centre_east_m
    v = north - motion.shift_north_m - motion.centre_north_m
    ox = motion.centre_east_m + inverse[0, 0] * u + inverse[0, 1] * v
    oy = motion.centre_north_m + inverse[1, 0] * u + inverse[1, 1] * v
    return pattern(ox, oy)


def test_a_tile_of_a_rotated_post_is_the_orthophoto_rotated(orthophoto: Path) -> None:
    # A tile (about 0.2 m a pixel) 20-45 m from the rotation's centre: 3° moves it 1-2 m.
    bounds = bounds_of(tile_over(WEST + 60.0, NORTH - 40.0, 19))
    with rasterio.open(orthophoto) as dataset:
        image = moved_image(dataset, bounds, CRS.from_epsg(3857), 256, MOTION)
        shift_only = dataclasses.replace(MOTION, rotation_deg=0.0)
        unrotated = moved_image(dataset, bounds, CRS.from_epsg(3857), 256, shift_only)
    seen = ~image.array.mask[0]
    assert seen.mean() > 0.95  # the tile lies inside the orthophoto
    error = np.abs(image.array.data.astype(float) - expected_colours(bounds, MOTION))[:, seen]
    assert error.mean() < 1.5 and np.percentile(error, 99) < 4, (error.mean(), error.max())
    # Left unrotated, the same tile is off by tens of grey levels.
    off = np.abs(unrotated.array.data.astype(float) - expected_colours(bounds, MOTION))[:, seen]
    assert off.mean() > 15, off.mean()


def test_outside_the_orthophoto_the_tile_is_masked(orthophoto: Path) -> None:
    bounds = bounds_of(tile_over(WEST + 300.0, NORTH - 300.0, 19))
    with rasterio.open(orthophoto) as dataset:
        image = moved_image(dataset, bounds, CRS.from_epsg(3857), 256, MOTION)
    assert image.array.mask.all()


def test_the_motion_undoes_the_co_registration_of_points() -> None:
    """The map's motion is the co-registration's: a point of post it corrects to p is
    found back where it was."""
    result = CoregisterResult(
        **{
            f.name: 0.0
            for f in dataclasses.fields(CoregisterResult)
            if f.default is dataclasses.MISSING
        }
        | {
            "horizontal_estimated": True,
            "iterations": 1,
            "notes": [],
            "tilt_east_m_per_km": None,
            "tilt_north_m_per_km": None,
        },
    )
    result = dataclasses.replace(
        result,
        shift_east_m=MOTION.shift_east_m,
        shift_north_m=MOTION.shift_north_m,
        rotation_deg=MOTION.rotation_deg,
        tilt_pivot_east_m=MOTION.centre_east_m,
        tilt_pivot_north_m=MOTION.centre_north_m,
    )
    rng = np.random.default_rng(3)
    points = np.column_stack(
        [WEST + rng.uniform(0, 100, 50), NORTH - rng.uniform(0, 100, 50), np.zeros(50)]
    )
    moved = result.correct_points(points)
    back = MOTION.origin_of(moved[:, 0], moved[:, 1])
    np.testing.assert_allclose(np.column_stack(back), points[:, :2], atol=1e-6)


def test_the_motion_is_read_from_the_comparison_summary() -> None:
    summary = {
        "shift_m": {"east": -1.3, "north": 0.7, "up": 0.2},
        "rotation_deg": 0.02,
        "stages": {
            "align": {"crs": UTM},
            "coregister": {"tilt_pivot_east_m": 500_120.0, "tilt_pivot_north_m": 5_099_880.0},
        },
    }
    assert motion_from_summary(summary) == PostMotion(-1.3, 0.7, 0.02, 500_120.0, 5_099_880.0, UTM)
    # Made before rotations were estimated: no centre, so the shift alone.
    older = {"shift_m": {"east": -1.3, "north": 0.7}, "rotation_deg": 0.02}
    assert motion_from_summary(older) == PostMotion(-1.3, 0.7)
    assert motion_from_summary({"detections": 0}) is None


def comparison_with_orthophoto(
    app: FastAPI, client: TestClient, auth: dict, orthophoto: Path
) -> dict:
    """A site whose post survey has `orthophoto`, and a finished comparison whose summary
    states MOTION as its co-registration did (shift, rotation, its grid's centre and CRS)."""
    site = client.post("/api/v1/sites", json={"name": "turned flight"}, headers=auth).json()["id"]
    storage = app.state.settings.storage_dir
    relative = f"products/{site}/orthophoto.tif"
    (storage / relative).parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(orthophoto, storage / relative)
    with app.state.sessionmaker() as session:
        surveys = [
            Survey(site_id=site, name=name, captured_at=datetime(2026, month, 1, tzinfo=UTC),
                   kind=SurveyKind.video, status=SurveyStatus.ready, crs=UTM)
            for name, month in (("June", 6), ("July", 7))
        ]  # fmt: skip
        stored = StoredFile(path=relative, size_bytes=orthophoto.stat().st_size,
                            sha256=hashlib.sha256(orthophoto.read_bytes()).hexdigest(),
                            media_type="image/tiff", original_name="orthophoto.tif")  # fmt: skip
        session.add_all([*surveys, stored])
        session.flush()
        session.add(Product(site_id=site, survey_id=surveys[1].id, kind="orthophoto",
                            file_id=stored.id, crs=UTM))  # fmt: skip
        summary = {
            "shift_m": {"east": MOTION.shift_east_m, "north": MOTION.shift_north_m, "up": 0.0},
            "rotation_deg": MOTION.rotation_deg,
            "stages": {
                "align": {"crs": UTM},
                "coregister": {
                    "tilt_pivot_east_m": MOTION.centre_east_m,
                    "tilt_pivot_north_m": MOTION.centre_north_m,
                },
            },
        }
        comparison = Comparison(site_id=site, pre_survey_id=surveys[0].id,
                                post_survey_id=surveys[1].id, method="threshold", parameters={},
                                status=JobState.succeeded, summary=summary,
                                finished_at=datetime.now(UTC))  # fmt: skip
        session.add(comparison)
        session.commit()
        return {"site": site, "post": surveys[1].id, "comparison": comparison.id}


def test_the_api_draws_the_post_orthophoto_turned_and_shifted(
    embedded_app: FastAPI, orthophoto: Path
) -> None:
    """`?coregistered_by=` on the post survey's orthophoto tiles: the tile is the
    orthophoto turned and shifted as the comparison's summary states."""
    with TestClient(embedded_app) as client:
        auth = {"Authorization": f"Bearer {token_for(embedded_app)}"}
        ids = comparison_with_orthophoto(embedded_app, client, auth, orthophoto)
        tile = tile_over(WEST + 60.0, NORTH - 40.0, 19)
        bounds = bounds_of(tile)
        survey = f"/api/v1/sites/{ids['site']}/surveys/{ids['post']}"
        url = f"{survey}/tiles/orthophoto/{tile.z}/{tile.x}/{tile.y}.png"
        moved = client.get(url, params={"coregistered_by": ids["comparison"]}, headers=auth)
        plain = client.get(url, headers=auth)
    assert moved.status_code == 200, moved.text
    rgba = np.asarray(Image.open(io.BytesIO(moved.content)).convert("RGBA")).astype(float)
    seen = rgba[..., 3] > 0
    assert seen.mean() > 0.95
    error = np.abs(np.moveaxis(rgba[..., :3], -1, 0) - expected_colours(bounds, MOTION))[:, seen]
    assert error.mean() < 1.5 and np.percentile(error, 99) < 4, (error.mean(), error.max())
    assert moved.headers["etag"] != plain.headers["etag"]

"""Inputs that cannot hurt the server: raster bombs refused from their header, bounded ids,
bounded bodies, checked GeoJSON and cron expressions that fire.

Each refusal is a 4xx that names what is wrong (and the setting, for a limit) and leaves
no row or file behind.
"""

import base64
import time
from pathlib import Path

import pytest
import rasterio
import rasterio.transform
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import func, select, update

from backend.db.models import Site, StoredFile, Survey, Upload
from backend.tiff_header import read_tiff_images
from tests.raster_bombs import write_bomb
from worker.simulator.dsm_pair import DsmPairPaths

HUGE = str(2**63)


def ring(*points: tuple) -> dict:
    return {"type": "Polygon", "coordinates": [[list(p) for p in points]]}


AREA = {"type": "Polygon", "coordinates": [[[9.0, 46.0], [9.1, 46.0], [9.1, 46.1], [9.0, 46.0]]]}


@pytest.fixture
def site_id(client: TestClient, auth: dict) -> int:
    return client.post("/api/v1/sites", json={"name": "slope"}, headers=auth).json()["id"]


def nothing_kept(app: FastAPI) -> bool:
    with app.state.sessionmaker() as session:
        rows = sum(
            session.scalar(select(func.count()).select_from(m)) for m in (Survey, StoredFile)
        )
    surveys = app.state.settings.storage_dir / "sites"
    files = [p for p in surveys.rglob("*") if p.is_file()] if surveys.exists() else []
    return rows == 0 and files == []


def post_dsm(client: TestClient, auth: dict, site_id: int, path: Path):
    return client.post(
        f"/api/v1/sites/{site_id}/surveys",
        params={"captured_at": "2026-06-01T10:00:00Z", "filename": path.name},
        content=path.read_bytes(),
        headers={**auth, "Content-Type": "image/tiff"},
    )


# --- rasters -------------------------------------------------------------------------------


def test_a_200_megapixel_bomb_is_refused_from_its_header_at_once(
    client: TestClient, auth: dict, site_id: int, app: FastAPI, tmp_path: Path
) -> None:
    bomb = write_bomb(tmp_path / "bomb.tif", 14143, 14143)  # 200 Mpx of zeros in 0.8 MB
    assert bomb.stat().st_size < 1_000_000
    started = time.perf_counter()
    response = post_dsm(client, auth, site_id, bomb)
    assert time.perf_counter() - started < 1.0
    assert response.status_code == 422
    assert "SLIDEWATCH_MAX_RASTER_COMPRESSION_RATIO" in response.json()["detail"]
    assert nothing_kept(app)


def test_one_strip_of_20000_by_20000_pixels_is_refused_naming_the_block_limit(
    client: TestClient, auth: dict, site_id: int, app: FastAPI, tmp_path: Path
) -> None:
    """The 1.5 MB file that kept the API busy for 15 minutes at 5.2 GB."""
    bomb = write_bomb(tmp_path / "strip.tif", 20000, 20000, block=None)
    app.state.settings.max_raster_compression_ratio = 1e9  # so that the block limit speaks
    response = post_dsm(client, auth, site_id, bomb)
    assert response.status_code == 422
    detail = response.json()["detail"]
    assert "20000 × 20000" in detail and "SLIDEWATCH_MAX_RASTER_BLOCK_BYTES" in detail
    assert nothing_kept(app)


def test_a_header_of_200000_by_200000_pixels_is_refused_naming_the_pixel_limit(
    client: TestClient, auth: dict, site_id: int, app: FastAPI, tmp_path: Path
) -> None:
    huge = write_bomb(tmp_path / "huge.tif", 200_000, 200_000, block=None, header_only=True)
    response = post_dsm(client, auth, site_id, huge)
    assert response.status_code == 422
    detail = response.json()["detail"]
    assert "40000000000 pixels" in detail and "SLIDEWATCH_MAX_RASTER_PIXELS" in detail
    assert nothing_kept(app)


def test_the_limits_are_settings(
    client: TestClient, auth: dict, site_id: int, app: FastAPI, dsm_pair_files: DsmPairPaths
) -> None:
    app.state.settings.max_raster_dimension = 200
    response = post_dsm(client, auth, site_id, dsm_pair_files.pre)  # 240 × 240
    assert response.status_code == 422
    assert "limit of 200 (SLIDEWATCH_MAX_RASTER_DIMENSION)" in response.json()["detail"]
    app.state.settings.max_raster_dimension = 240
    assert post_dsm(client, auth, site_id, dsm_pair_files.pre).status_code == 201


def test_a_bomb_sent_as_a_resumable_upload_fails_the_upload(
    client: TestClient, auth: dict, site_id: int, app: FastAPI, tmp_path: Path
) -> None:
    data = write_bomb(tmp_path / "bomb.tif", 14143, 14143).read_bytes()
    values = {"site_id": str(site_id), "filename": "bomb.tif", "captured_at": "2026-06-01"}
    meta = ",".join(f"{k} {base64.b64encode(v.encode()).decode()}" for k, v in values.items())
    tus = {**auth, "Tus-Resumable": "1.0.0"}
    created = client.post(
        "/api/v1/uploads", headers={**tus, "Upload-Length": str(len(data)), "Upload-Metadata": meta}
    )
    sent = client.patch(
        created.headers["Location"],
        content=data,
        headers={
            **tus,
            "Upload-Offset": "0",
            "Content-Type": "application/offset+octet-stream",
        },
    )
    assert sent.status_code == 422
    assert "SLIDEWATCH_MAX_RASTER_COMPRESSION_RATIO" in sent.json()["detail"]
    with app.state.sessionmaker() as session:
        assert session.scalar(select(Upload.state)) == "failed"
    assert nothing_kept(app)


@pytest.mark.parametrize(
    "options",
    [{"BIGTIFF": "YES"}, {"ENDIANNESS": "BIG"}, {"TILED": "YES", "COMPRESS": "DEFLATE"}, {}],
    ids=["bigtiff", "big-endian", "tiled", "striped"],
)
def test_the_header_reader_agrees_with_gdal(tmp_path: Path, options: dict) -> None:
    path = tmp_path / "dsm.tif"
    profile = {"driver": "GTiff", "width": 300, "height": 200, "count": 2, "dtype": "float32"}
    transform = rasterio.transform.from_origin(500000, 5100000, 1, 1)
    with rasterio.open(path, "w", **profile, **options, crs="EPSG:32632", transform=transform):
        pass
    with rasterio.open(path) as src:
        block_height, block_width = src.block_shapes[0]
    image = read_tiff_images(path)[0]
    assert (image.width, image.height, image.samples) == (300, 200, 2)
    assert (image.block_width, image.block_height) == (block_width, block_height)
    assert image.bits_per_sample == 32


# --- ids, bodies, GeoJSON, cron ------------------------------------------------------------


@pytest.mark.parametrize(
    "method, path, body",
    [
        ("get", f"/api/v1/sites/{HUGE}", None),
        ("get", "/api/v1/sites/{site}/surveys/" + HUGE, None),
        ("delete", "/api/v1/sites/{site}/surveys/" + HUGE, None),
        ("get", "/api/v1/sites/{site}/jobs/" + "9" * 5000, None),
        ("post", "/api/v1/sites/{site}/comparisons", {"pre_survey_id": HUGE, "post_survey_id": 1}),
        ("post", "/api/v1/sites/{site}/reports", {"comparison_id": 2**64}),
        ("get", f"/ogc/collections/detections/items?comparison_id={HUGE}", None),
    ],
)
def test_ids_beyond_any_row_are_refused_naming_the_bound(
    client: TestClient, auth: dict, site_id: int, method: str, path: str, body: dict | None
) -> None:
    kwargs = {"json": body} if body is not None else {}
    response = client.request(method, path.format(site=site_id), headers=auth, **kwargs)
    assert response.status_code == 422, response.text
    assert "2147483647" in response.text or "exceeded maximum size" in response.text


def test_ids_beyond_any_row_in_tus_metadata_and_ogc_paths_are_not_found(
    client: TestClient, auth: dict
) -> None:
    meta = ",".join(f"{k} {base64.b64encode(v.encode()).decode()}" for k, v in
                    {"site_id": HUGE, "filename": "a.tif"}.items())  # fmt: skip
    created = client.post(
        "/api/v1/uploads",
        headers={**auth, "Tus-Resumable": "1.0.0", "Upload-Length": "10", "Upload-Metadata": meta},
    )
    assert created.status_code == 404 and HUGE in created.json()["detail"]
    feature = client.get(f"/ogc/collections/sites/items/{'9' * 5000}", headers=auth)
    assert feature.status_code == 404


def test_a_json_body_over_the_limit_is_refused_before_it_is_read(
    client: TestClient, auth: dict
) -> None:
    description = "x" * (3 * 1024**2)
    response = client.post(
        "/api/v1/sites", json={"name": "big", "description": description}, headers=auth
    )
    assert response.status_code == 413
    assert "SLIDEWATCH_MAX_REQUEST_BYTES" in response.json()["detail"]

    def chunks():  # no Content-Length: counted as it arrives
        yield b'{"name": "big", "description": "'
        for _ in range(30):
            yield b"x" * 100_000
        yield b'"}'

    streamed = client.post(
        "/api/v1/sites", content=chunks(), headers={**auth, "Content-Type": "application/json"}
    )
    assert streamed.status_code == 413
    assert client.get("/api/v1/sites", headers=auth).json() == []


def test_uploads_are_held_to_the_upload_limit_not_the_request_limit(
    client: TestClient, auth: dict, site_id: int, app: FastAPI
) -> None:
    body = b"II*\0" + bytes(3 * 1024**2)  # past the 2 MiB of JSON routes
    response = client.post(
        f"/api/v1/sites/{site_id}/surveys",
        params={"captured_at": "2026-06-01T10:00:00Z"},
        content=body,
        headers={**auth, "Content-Type": "image/tiff"},
    )
    assert response.status_code == 422 and "not a readable GeoTIFF" in response.json()["detail"]
    app.state.settings.max_upload_bytes = 1024**2
    response = client.post(
        f"/api/v1/sites/{site_id}/surveys",
        params={"captured_at": "2026-06-01T10:00:00Z"},
        content=body,
        headers={**auth, "Content-Type": "image/tiff"},
    )
    assert response.status_code == 413 and str(1024**2) in response.json()["detail"]
    assert nothing_kept(app)


def test_a_long_description_within_the_limit_is_still_refused_by_its_own_bound(
    client: TestClient, auth: dict
) -> None:
    response = client.post(
        "/api/v1/sites", json={"name": "long", "description": "x" * 20_000}, headers=auth
    )
    assert response.status_code == 422
    assert "10000 characters" in response.text


@pytest.mark.parametrize(
    "area, says",
    [
        ("not geojson", "valid dictionary"),
        ({"type": "Point", "coordinates": [9, 46]}, "Polygon or MultiPolygon, not 'Point'"),
        ({"type": "Polygon", "coordinates": "x"}, "non-empty list"),
        ({"type": "Polygon", "coordinates": [[[9, 46], [9.1, 46], [9, 46]]]}, "at least 4"),
        (ring((9, 46), (9.1, 46), (9.1, 46.1), (9, 46.2)), "end at"),
        (ring((900, 46), (9.1, 46), (9.1, 46.1), (900, 46)), "WGS84"),
        (ring(("a", 46), (9.1, 46), (9.1, 46.1), ("a", 46)), "finite"),
        (ring((0, 0), (1, 1), (1, 0), (0, 1), (0, 0)), "Self-intersection"),
    ],
)  # fmt: skip
def test_an_area_of_interest_that_is_not_a_geojson_polygon_is_refused(
    client: TestClient, auth: dict, site_id: int, area, says: str
) -> None:
    created = client.post(
        "/api/v1/sites", json={"name": "aoi", "area_of_interest": area}, headers=auth
    )
    assert created.status_code == 422 and says in created.text, created.text
    patched = client.patch(
        f"/api/v1/sites/{site_id}", json={"area_of_interest": area}, headers=auth
    )
    assert patched.status_code == 422 and says in patched.text
    assert client.get(f"/api/v1/sites/{site_id}", headers=auth).json()["area_of_interest"] is None


def test_a_stored_area_that_is_not_geojson_does_not_break_the_collections(
    client: TestClient, auth: dict, site_id: int, app: FastAPI
) -> None:
    assert (
        client.patch(
            f"/api/v1/sites/{site_id}", json={"area_of_interest": AREA}, headers=auth
        ).json()["area_of_interest"]
        == AREA
    )
    with app.state.sessionmaker() as session:  # a row saved before areas were checked
        session.execute(update(Site).values(area_of_interest={"type": "Polygon"}))
        session.commit()
    assert client.get("/ogc/collections", headers=auth).status_code == 200
    items = client.get("/ogc/collections/sites/items", headers=auth)
    assert items.status_code == 200 and items.json()["features"][0]["geometry"] is None


@pytest.mark.parametrize("cron", ["0 0 30 2 *", "0 0 31 4,6 *"])
def test_a_cron_expression_that_never_fires_is_refused(
    client: TestClient, auth: dict, site_id: int, cron: str
) -> None:
    schedules = f"/api/v1/sites/{site_id}/schedules"
    response = client.post(schedules, json={"cron": cron}, headers=auth)
    assert response.status_code == 422 and "never fires" in response.json()["detail"]
    made = client.post(schedules, json={"cron": "0 6 * * 1"}, headers=auth).json()
    patched = client.patch(f"{schedules}/{made['id']}", json={"cron": cron}, headers=auth)
    assert patched.status_code == 422 and "never fires" in patched.json()["detail"]
    assert client.get(f"{schedules}/{made['id']}", headers=auth).json()["cron"] == "0 6 * * 1"

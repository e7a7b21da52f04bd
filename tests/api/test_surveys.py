"""Surveys from uploaded DSM GeoTIFFs: checks, checksums, limits, and clean failures."""

import hashlib
from pathlib import Path

import numpy as np
import pytest
import rasterio
from fastapi import FastAPI
from fastapi.testclient import TestClient
from rasterio.transform import from_origin
from sqlalchemy import func, select

from backend.db.models import Product, StoredFile, Survey
from tests.api_helpers import upload_dsm
from worker.simulator.dsm_pair import DsmPairPaths


@pytest.fixture
def site_id(client: TestClient, auth: dict) -> int:
    return client.post("/api/v1/sites", json={"name": "slope"}, headers=auth).json()["id"]


def stored_state(app: FastAPI) -> tuple[int, int, int, list[Path]]:
    """Rows and files kept: (surveys, stored files, products, files on disk)."""
    with app.state.sessionmaker() as session:
        counts = [
            session.scalar(select(func.count()).select_from(m))
            for m in (Survey, StoredFile, Product)
        ]
    root = app.state.settings.storage_dir
    files = sorted(p for p in root.rglob("*") if p.is_file()) if root.exists() else []
    return counts[0], counts[1], counts[2], files


def test_upload_keeps_checksum_crs_and_footprint(
    client: TestClient, auth: dict, site_id: int, dsm_pair_files: DsmPairPaths
) -> None:
    survey = upload_dsm(client, auth, site_id, dsm_pair_files.pre, "2026-06-01T10:00:00Z")
    data = dsm_pair_files.pre.read_bytes()
    assert survey["kind"] == "dsm"
    assert survey["status"] == "ready"
    assert survey["crs"] == "EPSG:32632"
    assert survey["resolution_m"] == pytest.approx(1.0)
    assert survey["source_file"]["sha256"] == hashlib.sha256(data).hexdigest()
    assert survey["source_file"]["size_bytes"] == len(data)
    assert survey["footprint"]["type"] == "Polygon"
    lon, lat = survey["footprint"]["coordinates"][0][0]
    assert 6 < lon < 12 and 0 < lat < 84  # UTM zone 32 north

    products = client.get(
        f"/api/v1/sites/{site_id}/surveys/{survey['id']}/products", headers=auth
    ).json()
    assert [p["kind"] for p in products] == ["dsm"]
    download = client.get(products[0]["download_url"], headers=auth)
    assert download.status_code == 200
    # The DSM product is a Cloud-Optimized GeoTIFF made from the upload: same pixels.
    assert "cloud-optimized" in products[0]["file"]["media_type"]
    with (
        rasterio.MemoryFile(download.content) as memory,
        memory.open() as cog,
        rasterio.open(dsm_pair_files.pre) as original,
    ):
        assert np.array_equal(cog.read(1), original.read(1))
        assert cog.crs == original.crs and cog.nodata == original.nodata
        assert cog.overviews(1) == [] and cog.profile["tiled"]  # 240 px: one tile, no overviews


def test_product_download_supports_range_requests(
    client: TestClient, auth: dict, site_id: int, dsm_pair_files: DsmPairPaths
) -> None:
    survey = upload_dsm(client, auth, site_id, dsm_pair_files.pre, "2026-06-01T10:00:00Z")
    url = client.get(
        f"/api/v1/sites/{site_id}/surveys/{survey['id']}/products", headers=auth
    ).json()[0]["download_url"]
    whole = client.get(url, headers=auth).content
    partial = client.get(url, headers={**auth, "Range": "bytes=100-199"})
    assert partial.status_code == 206
    assert partial.content == whole[100:200]
    assert partial.headers["content-range"].startswith("bytes 100-199/")


def test_surveys_are_listed_by_capture_time(
    client: TestClient, auth: dict, site_id: int, dsm_pair_files: DsmPairPaths
) -> None:
    later = upload_dsm(client, auth, site_id, dsm_pair_files.post, "2026-07-01T10:00:00+09:00")
    earlier = upload_dsm(client, auth, site_id, dsm_pair_files.pre, "2026-06-01T10:00:00")
    listed = client.get(f"/api/v1/sites/{site_id}/surveys", headers=auth).json()
    assert [s["id"] for s in listed] == [earlier["id"], later["id"]]


def _geotiff(path: Path, crs: str | None, data: np.ndarray, nodata: float = -9999.0) -> Path:
    with rasterio.open(
        path, "w", driver="GTiff", width=data.shape[1], height=data.shape[0], count=1,
        dtype="float32", crs=crs, transform=from_origin(500000, 4000000, 1, 1), nodata=nodata,
    ) as dst:  # fmt: skip
        dst.write(data.astype("float32"), 1)
    return path


def bad_inputs(tmp_path: Path, good: Path) -> dict[str, tuple[bytes, str]]:
    ramp = np.add.outer(np.arange(64.0), np.arange(64.0))
    no_crs = _geotiff(tmp_path / "nocrs.tif", None, ramp)
    all_nodata = _geotiff(tmp_path / "empty.tif", "EPSG:32632", np.full((64, 64), -9999.0))
    data = good.read_bytes()
    return {
        "not a GeoTIFF": (b"%PDF-1.7 this is a report, not a raster", "not a GeoTIFF"),
        "no CRS": (no_crs.read_bytes(), "no coordinate reference system"),
        "all nodata": (all_nodata.read_bytes(), "no valid elevation"),
        "truncated": (data[: len(data) * 2 // 3], "truncated"),
    }


@pytest.mark.parametrize("case", ["not a GeoTIFF", "no CRS", "all nodata", "truncated"])
def test_bad_uploads_are_refused_and_leave_nothing(
    client: TestClient, app: FastAPI, auth: dict, site_id: int, tmp_path: Path,
    dsm_pair_files: DsmPairPaths, case: str,
) -> None:  # fmt: skip
    body, expected = bad_inputs(tmp_path, dsm_pair_files.pre)[case]
    before = stored_state(app)
    response = client.post(
        f"/api/v1/sites/{site_id}/surveys",
        params={"captured_at": "2026-06-01T10:00:00Z"},
        content=body,
        headers={**auth, "Content-Type": "image/tiff"},
    )
    assert response.status_code == 422
    assert expected.lower() in response.json()["detail"].lower()
    assert stored_state(app) == before


def test_upload_above_the_size_limit_is_refused_and_leaves_nothing(
    client: TestClient, app: FastAPI, auth: dict, site_id: int, dsm_pair_files: DsmPairPaths
) -> None:
    app.state.settings.max_upload_bytes = 10_000
    before = stored_state(app)

    def body():  # streamed, so no Content-Length: the limit is enforced while writing
        data = dsm_pair_files.pre.read_bytes()
        for start in range(0, len(data), 4096):
            yield data[start : start + 4096]

    response = client.post(
        f"/api/v1/sites/{site_id}/surveys",
        params={"captured_at": "2026-06-01T10:00:00Z"},
        content=body(),
        headers={**auth, "Content-Type": "image/tiff"},
    )
    assert response.status_code == 413
    assert "limit of 10000 bytes" in response.json()["detail"]
    assert stored_state(app) == before

    declared = client.post(
        f"/api/v1/sites/{site_id}/surveys",
        params={"captured_at": "2026-06-01T10:00:00Z"},
        content=dsm_pair_files.pre.read_bytes(),
        headers={**auth, "Content-Type": "image/tiff"},
    )
    assert declared.status_code == 413
    assert stored_state(app) == before


def test_form_upload_is_refused_with_a_hint(client: TestClient, auth: dict, site_id: int) -> None:
    response = client.post(
        f"/api/v1/sites/{site_id}/surveys",
        params={"captured_at": "2026-06-01T10:00:00Z"},
        files={"file": ("dsm.tif", b"II*\x00")},
        headers=auth,
    )
    assert response.status_code == 415
    assert "raw request body" in response.json()["detail"]


def test_missing_capture_time_is_rejected(client: TestClient, auth: dict, site_id: int) -> None:
    response = client.post(f"/api/v1/sites/{site_id}/surveys", content=b"II*\x00", headers=auth)
    assert response.status_code == 422
    assert "captured_at" in response.text


def test_survey_of_another_site_is_not_served(
    client: TestClient, auth: dict, site_id: int, dsm_pair_files: DsmPairPaths
) -> None:
    other = client.post("/api/v1/sites", json={"name": "other"}, headers=auth).json()["id"]
    survey = upload_dsm(client, auth, site_id, dsm_pair_files.pre, "2026-06-01T10:00:00Z")
    product = client.get(
        f"/api/v1/sites/{site_id}/surveys/{survey['id']}/products", headers=auth
    ).json()[0]
    for path in (
        f"/api/v1/sites/{other}/surveys/{survey['id']}",
        f"/api/v1/sites/{other}/surveys/{survey['id']}/products",
        f"/api/v1/sites/{other}/products/{product['id']}",
        f"/api/v1/sites/{other}/products/{product['id']}/file",
    ):
        response = client.get(path, headers=auth)
        assert response.status_code == 404, path
        assert f"not found in site {other}" in response.json()["detail"]
    assert (
        client.delete(f"/api/v1/sites/{other}/surveys/{survey['id']}", headers=auth).status_code
        == 404
    )


def test_deleting_a_survey_removes_its_file(
    client: TestClient, app: FastAPI, auth: dict, site_id: int, dsm_pair_files: DsmPairPaths
) -> None:
    before = stored_state(app)
    survey = upload_dsm(client, auth, site_id, dsm_pair_files.pre, "2026-06-01T10:00:00Z")
    assert stored_state(app)[3] != before[3]
    assert (
        client.delete(f"/api/v1/sites/{site_id}/surveys/{survey['id']}", headers=auth).status_code
        == 204
    )
    assert stored_state(app) == before

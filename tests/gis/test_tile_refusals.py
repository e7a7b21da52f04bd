"""Tile endpoints read only our own products: no client path, no URL, no other site's
product, no VRT (which could make GDAL read any file on the machine)."""

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import select

from backend.db.models import Product
from backend.geotiff import NotGeoTiff, open_geotiff
from tests.monitoring_helpers import finished_comparison, token_for
from worker.simulator.dsm_pair import DsmPairPaths

TILE_ROUTES = (
    "/api/v1/sites/{site_id}/surveys/{survey_id}/tiles/{layer}/{z}/{x}/{y}.png",
    "/api/v1/sites/{site_id}/comparisons/{comparison_id}/tiles/{layer}/{z}/{x}/{y}.png",
    "/api/v1/sites/{site_id}/surveys/{survey_id}/tiles/{layer}/tilejson.json",
    "/api/v1/sites/{site_id}/comparisons/{comparison_id}/tiles/{layer}/tilejson.json",
)


@pytest.fixture
def client(embedded_app: FastAPI) -> Iterator[TestClient]:
    with TestClient(embedded_app) as test_client:
        yield test_client


@pytest.fixture
def auth(embedded_app: FastAPI) -> dict[str, str]:
    return {"Authorization": f"Bearer {token_for(embedded_app)}"}


@pytest.fixture
def ids(client: TestClient, auth: dict, gis_pair: DsmPairPaths) -> dict[str, int]:
    return finished_comparison(client, auth, gis_pair)


def _tile_of(client: TestClient, auth: dict, base: str) -> str:
    import morecantile

    tilejson = client.get(f"{base}/tilejson.json", headers=auth).json()
    west, south, east, north = tilejson["bounds"]
    tile = morecantile.tms.get("WebMercatorQuad").tile(
        (west + east) / 2, (south + north) / 2, tilejson["maxzoom"] - 2
    )
    return f"{base}/{tile.z}/{tile.x}/{tile.y}.png"


def test_no_tile_endpoint_takes_a_path_or_url_parameter(embedded_app: FastAPI) -> None:
    paths = embedded_app.openapi()["paths"]
    for route in TILE_ROUTES:
        names = {p["name"] for p in paths[route]["get"].get("parameters", [])}
        assert names.isdisjoint({"url", "path", "file", "src", "dataset"}), (route, names)


QUERIES = ["url=/etc/passwd", "url=https://example.com/x.tif", "path=../../slidewatch.db"]
LAYER_SEGMENTS = [
    "..%2F..%2F..%2Fetc%2Fpasswd",
    "%2Fetc%2Fpasswd",
    "file:%2F%2F%2Fetc%2Fpasswd",
    "..",
    "dh.vrt",
]
ID_SEGMENTS = ["..%2F1", "%2Fetc%2Fpasswd", "1.tif", "http:%2F%2Fx"]


def test_paths_and_urls_from_the_client_are_never_read(
    client: TestClient, auth: dict, ids: dict
) -> None:
    # (One comparison for every case: each costs a full comparison job.)
    tile = _tile_of(
        client, auth, f"/api/v1/sites/{ids['site']}/comparisons/{ids['comparison']}/tiles/dh"
    )
    plain = client.get(tile, headers=auth)
    assert plain.status_code == 200
    for query in QUERIES:  # a path or URL in the query changes nothing
        assert client.get(f"{tile}?{query}", headers=auth).content == plain.content, query
    for segment in LAYER_SEGMENTS:  # in place of a layer name: not found
        for owner, owner_id in (("surveys", ids["pre"]), ("comparisons", ids["comparison"])):
            base = f"/api/v1/sites/{ids['site']}/{owner}/{owner_id}/tiles"
            for url in (f"{base}/{segment}/18/0/0.png", f"{base}/{segment}/tilejson.json"):
                response = client.get(url, headers=auth)
                assert response.status_code == 404, (url, response.text)
                assert b"root:" not in response.content
    for owner_id in ID_SEGMENTS:  # in place of an id: refused
        for owner in ("surveys", "comparisons"):
            url = f"/api/v1/sites/{ids['site']}/{owner}/{owner_id}/tiles/dsm/18/0/0.png"
            assert client.get(url, headers=auth).status_code in (404, 422), url


def test_other_sites_products_are_refused(client: TestClient, auth: dict, ids: dict) -> None:
    other = client.post("/api/v1/sites", json={"name": "other site"}, headers=auth).json()["id"]
    theirs = f"/api/v1/sites/{ids['site']}"
    mine = f"/api/v1/sites/{other}"
    for path in (
        f"/surveys/{ids['pre']}/tiles/dsm/tilejson.json",
        f"/surveys/{ids['post']}/tiles/hillshade/tilejson.json",
        f"/comparisons/{ids['comparison']}/tiles/dh/tilejson.json",
    ):
        assert client.get(theirs + path, headers=auth).status_code == 200
        response = client.get(mine + path, headers=auth)
        assert response.status_code == 404
        assert f"not found in site {other}" in response.json()["detail"]
    tile = _tile_of(client, auth, f"{theirs}/comparisons/{ids['comparison']}/tiles/dh")
    assert client.get(tile.replace(theirs, mine), headers=auth).status_code == 404
    wmts = client.get(f"{mine}/wmts/WMTSCapabilities.xml", headers=auth).text
    assert f"comparison-{ids['comparison']}" not in wmts and f"survey-{ids['pre']}" not in wmts


def test_a_product_that_is_a_vrt_is_never_read(
    client: TestClient, auth: dict, ids: dict, embedded_app: FastAPI, tmp_path: Path
) -> None:
    """Should a product file ever be a VRT (which can name any file: here the database),
    neither its tiles nor its TileJSON are served, and the site's WMTS leaves it out."""
    storage = embedded_app.state.storage
    with embedded_app.state.sessionmaker() as session:
        product = session.scalar(
            select(Product).where(Product.comparison_id == ids["comparison"], Product.kind == "dh")
        )
        target = storage.absolute(product.file.path)
    secret = embedded_app.state.settings.data_dir / "slidewatch.db"
    target.write_text(
        '<VRTDataset rasterXSize="64" rasterYSize="64"><VRTRasterBand dataType="Byte" band="1">'
        f'<SimpleSource><SourceFilename relativeToVRT="0">{secret}</SourceFilename>'
        "<SourceBand>1</SourceBand></SimpleSource></VRTRasterBand></VRTDataset>"
    )
    base = f"/api/v1/sites/{ids['site']}/comparisons/{ids['comparison']}/tiles/dh"
    for url in (f"{base}/tilejson.json", f"{base}/18/0/0.png"):
        response = client.get(url, headers=auth)
        assert response.status_code == 404
        assert "not a GeoTIFF" in response.json()["detail"]
    wmts = client.get(f"/api/v1/sites/{ids['site']}/wmts/WMTSCapabilities.xml", headers=auth)
    assert wmts.status_code == 200 and f"comparison-{ids['comparison']}-dh" not in wmts.text
    with pytest.raises(NotGeoTiff):
        open_geotiff(target)


def test_a_vrt_uploaded_as_a_dsm_is_refused_unread(
    client: TestClient, auth: dict, ids: dict, embedded_app: FastAPI, gis_pair: DsmPairPaths
) -> None:
    """A VRT pointing at a real DSM is a raster GDAL would read; as an upload it is refused
    for not being a TIFF, before GDAL sees it, and leaves no survey."""
    import rasterio

    with rasterio.open(gis_pair.pre) as src:
        width, height = src.width, src.height
    vrt = (
        f'<VRTDataset rasterXSize="{width}" rasterYSize="{height}">'
        '<VRTRasterBand dataType="Float32" band="1"><SimpleSource>'
        f'<SourceFilename relativeToVRT="0">{gis_pair.pre}</SourceFilename>'
        "<SourceBand>1</SourceBand></SimpleSource></VRTRasterBand></VRTDataset>"
    ).encode()
    before = client.get(f"/api/v1/sites/{ids['site']}/surveys", headers=auth).json()
    response = client.post(
        f"/api/v1/sites/{ids['site']}/surveys",
        params={"captured_at": "2026-08-01T10:00:00Z", "filename": "other-site.tif"},
        content=vrt,
        headers={**auth, "Content-Type": "image/tiff"},
    )
    assert response.status_code == 422
    assert "not a GeoTIFF (it is not a TIFF file)" in response.json()["detail"]
    assert client.get(f"/api/v1/sites/{ids['site']}/surveys", headers=auth).json() == before


def test_tiles_of_a_fine_dsm_render_at_every_zoom(
    client: TestClient, auth: dict, embedded_app: FastAPI, tmp_path: Path
) -> None:
    """A 2 cm DSM (as reconstructions give) with overviews: every zoom renders, including
    those where rio-tiler builds its own in-memory VRTs (which GDAL_SKIP=VRT would break)."""
    import morecantile
    import numpy as np
    import rasterio
    from rasterio.transform import from_origin

    from tests.api_helpers import upload_dsm

    path = tmp_path / "fine.tif"
    ramp = np.add.outer(np.arange(900.0), np.arange(700.0)).astype("float32") * 0.001 + 20
    profile = {
        "driver": "GTiff", "width": 700, "height": 900, "count": 1, "dtype": "float32",
        "crs": "EPSG:32654", "transform": from_origin(419339.48, 3990838.22, 0.02, 0.02),
        "nodata": -9999.0,
    }  # fmt: skip
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(ramp, 1)
    site = client.post("/api/v1/sites", json={"name": "fine"}, headers=auth).json()["id"]
    survey = upload_dsm(client, auth, site, path, "2026-06-01T10:00:00Z")["id"]
    base = f"/api/v1/sites/{site}/surveys/{survey}/tiles"
    tilejson = client.get(f"{base}/dsm/tilejson.json", headers=auth).json()
    west, south, east, north = tilejson["bounds"]
    tms = morecantile.tms.get("WebMercatorQuad")
    for z in range(max(tilejson["minzoom"], tilejson["maxzoom"] - 6), tilejson["maxzoom"] + 1):
        tile = tms.tile((west + east) / 2, (south + north) / 2, z)
        for layer in ("dsm", "hillshade"):
            response = client.get(f"{base}/{layer}/{z}/{tile.x}/{tile.y}.png", headers=auth)
            assert response.status_code == 200, (layer, z, response.text[:200])
    # Also in a fresh process that imports the app, as `slidewatch api` does: GDAL settings
    # made at import (GDAL_SKIP=VRT broke every tile) act only before GDAL starts.
    z = tilejson["maxzoom"] - 2
    tile = tms.tile((west + east) / 2, (south + north) / 2, z)
    with embedded_app.state.sessionmaker() as session:
        product = session.scalar(
            select(Product).where(Product.survey_id == survey, Product.kind == "dsm")
        )
        cog = embedded_app.state.storage.absolute(product.file.path)
    script = (
        "import backend.api.app\n"
        "from backend.services.tiles import SURVEY_LAYERS, render_tile\n"
        f"render_tile({str(cog)!r}, SURVEY_LAYERS['dsm'], {z}, {tile.x}, {tile.y})\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]

"""Map layers: XYZ tiles and TileJSON, a WMTS capabilities document that OWSLib parses and
whose tiles render, COG products readable over HTTP Range, and a STAC catalog."""

import io
from collections.abc import Iterator

import morecantile
import numpy as np
import pystac
import pytest
import rasterio
from fastapi import FastAPI
from fastapi.testclient import TestClient
from owslib.wmts import WebMapTileService
from PIL import Image
from rio_cogeo.cogeo import cog_validate

from backend.config import Settings
from tests.monitoring_helpers import LiveServer, app_for, finished_comparison, token_for
from worker.simulator.dsm_pair import DsmPairPaths

TMS = morecantile.tms.get("WebMercatorQuad")


@pytest.fixture(scope="module")
def compared(
    tmp_path_factory: pytest.TempPathFactory, gis_pair: DsmPairPaths
) -> Iterator[tuple[FastAPI, dict[str, int]]]:
    """An app on the embedded default with one finished comparison, and its ids: made once
    for the tests here that only read it (running the comparison takes seconds)."""
    settings = Settings(data_dir=tmp_path_factory.mktemp("tiles") / "data")
    with pytest.MonkeyPatch.context() as monkeypatch, app_for(settings, monkeypatch) as app:
        with TestClient(app) as client:
            auth = {"Authorization": f"Bearer {token_for(app)}"}
            ids = finished_comparison(client, auth, gis_pair)
        yield app, ids


@pytest.fixture
def compared_app(compared: tuple[FastAPI, dict[str, int]]) -> FastAPI:
    return compared[0]


@pytest.fixture
def ids(compared: tuple[FastAPI, dict[str, int]]) -> dict[str, int]:
    return compared[1]


@pytest.fixture
def token(compared_app: FastAPI) -> str:
    return token_for(compared_app)


@pytest.fixture
def client(compared_app: FastAPI) -> Iterator[TestClient]:
    with TestClient(compared_app) as test_client:
        yield test_client


@pytest.fixture
def auth(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


def _png(content: bytes) -> np.ndarray:
    image = Image.open(io.BytesIO(content))
    assert image.format == "PNG" and image.size == (256, 256)
    return np.asarray(image.convert("RGBA"))


def _centre_tile(tilejson: dict) -> morecantile.Tile:
    west, south, east, north = tilejson["bounds"]
    return TMS.tile((west + east) / 2, (south + north) / 2, tilejson["maxzoom"] - 2)


def test_products_are_cogs_with_crs_and_nodata(client: TestClient, auth: dict, ids: dict) -> None:
    site, comparison, survey = ids["site"], ids["comparison"], ids["pre"]
    products = client.get(f"/api/v1/sites/{site}/comparisons/{comparison}/products", headers=auth)
    products = products.json()
    products += client.get(f"/api/v1/sites/{site}/surveys/{survey}/products", headers=auth).json()
    rasters = {p["kind"]: p for p in products if p["kind"] != "detections"}
    # lod: the per-pixel LoD95 of the difference stage, a COG in metres like dh.
    assert set(rasters) == {"dsm", "dh", "significance", "lod", "post_coregistered"}
    for kind, product in rasters.items():
        data = client.get(product["download_url"], headers=auth).content
        with rasterio.MemoryFile(data) as memory, memory.open() as src:
            assert src.crs.to_epsg() == 32632, kind
            assert src.nodata == (255 if kind == "significance" else -9999.0), kind
            assert src.profile["compress"] == "deflate", kind
            assert src.tags(ns="IMAGE_STRUCTURE").get("PREDICTOR") == (
                "2" if kind == "significance" else "3"
            ), kind
        with rasterio.MemoryFile(data) as memory:
            valid, errors, _ = cog_validate(memory.name, quiet=True)
            assert valid, (kind, errors)


def test_tiles_render_each_layer_with_its_style(client: TestClient, auth: dict, ids: dict) -> None:
    base = f"/api/v1/sites/{ids['site']}/comparisons/{ids['comparison']}/tiles"
    tilejson = client.get(f"{base}/dh/tilejson.json", headers=auth).json()
    # At the configured public URL (not the request's Host), with no token in it.
    assert tilejson["tiles"] == [f"http://127.0.0.1:8000{base}/dh/{{z}}/{{x}}/{{y}}.png"]
    tile = _centre_tile(tilejson)
    dh = _png(client.get(f"{base}/dh/{tile.z}/{tile.x}/{tile.y}.png", headers=auth).content)
    # Diverging colormap: the landslide's loss is blue, its deposit red, stable ground white.
    opaque = dh[dh[..., 3] == 255]
    assert (opaque[:, 2] > opaque[:, 0] + 80).any() and (opaque[:, 0] > opaque[:, 2] + 80).any()
    shade = _png(
        client.get(f"{base}/hillshade/{tile.z}/{tile.x}/{tile.y}.png", headers=auth).content
    )
    grey = shade[shade[..., 3] == 255]
    assert len(grey) > 1000 and (grey[:, 0] == grey[:, 1]).all() and grey[:, 0].std() > 2
    survey = f"/api/v1/sites/{ids['site']}/surveys/{ids['pre']}/tiles/dsm"
    dsm = client.get(f"{survey}/{tile.z}/{tile.x}/{tile.y}.png?colormap=viridis", headers=auth)
    assert dsm.status_code == 200 and _png(dsm.content)[..., 3].max() == 255


@pytest.mark.parametrize(
    ("suffix", "status", "message"),
    [
        ("dh/18/0/0.png", 404, "outside the layer"),
        ("dh/30/0/0.png", 404, "does not exist"),
        ("slope/18/0/0.png", 404, "unknown layer 'slope'"),
        ("dh/18/1/1.png?rescale=5,1", 400, "min must be smaller"),
        ("dh/18/1/1.png?colormap=rainbowz", 400, "unknown colormap"),
    ],
)
def test_bad_tile_requests_say_why(
    client: TestClient, auth: dict, ids: dict, suffix: str, status: int, message: str
) -> None:
    url = f"/api/v1/sites/{ids['site']}/comparisons/{ids['comparison']}/tiles/{suffix}"
    response = client.get(url, headers=auth)
    assert response.status_code == status
    assert message in response.json()["detail"]


@pytest.fixture
def own_client(embedded_app: FastAPI) -> Iterator[TestClient]:
    with TestClient(embedded_app) as test_client:
        yield test_client


@pytest.fixture
def own_auth(embedded_app: FastAPI) -> dict[str, str]:
    return {"Authorization": f"Bearer {token_for(embedded_app)}"}


@pytest.fixture
def own_ids(own_client: TestClient, own_auth: dict, gis_pair: DsmPairPaths) -> dict[str, int]:
    return finished_comparison(own_client, own_auth, gis_pair)


def test_tiles_are_only_ours_and_need_a_token(
    own_client: TestClient, own_auth: dict, own_ids: dict
) -> None:
    # An app of its own: the site it adds would be seen by the tests of the shared one.
    client, auth, ids = own_client, own_auth, own_ids
    other = client.post("/api/v1/sites", json={"name": "other"}, headers=auth).json()["id"]
    path = f"comparisons/{ids['comparison']}/tiles/dh/tilejson.json"
    assert client.get(f"/api/v1/sites/{other}/{path}", headers=auth).status_code == 404
    assert client.get(f"/api/v1/sites/{ids['site']}/{path}").status_code == 401
    url = f"/api/v1/sites/{ids['site']}/{path}?url=/etc/passwd"
    assert client.get(url, headers=auth).json()["tiles"][0].count("/etc/passwd") == 0


def test_wmts_capabilities_parse_and_their_tiles_render(
    compared_app: FastAPI, token: str, ids: dict
) -> None:
    with LiveServer(compared_app) as server:
        url = f"{server.url}/api/v1/sites/{ids['site']}/wmts/WMTSCapabilities.xml"
        # The tile templates carry no token: the client sends its header with each tile.
        wmts = WebMapTileService(url, headers={"Authorization": f"Bearer {token}"})
        assert token not in WebMapTileService(f"{url}?api_key={token}").getServiceXML().decode()
        names = set(wmts.contents)
        comparison, pre, post = ids["comparison"], ids["pre"], ids["post"]
        assert {
            f"comparison-{comparison}-dh",
            f"comparison-{comparison}-hillshade",
            f"survey-{pre}-dsm",
            f"survey-{post}-hillshade",
        } <= names
        assert "WebMercatorQuad" in wmts.tilematrixsets
        layer = wmts.contents[f"comparison-{comparison}-dh"]
        west, south, east, north = layer.boundingBoxWGS84
        tile = TMS.tile((west + east) / 2, (south + north) / 2, 18)
        response = wmts.gettile(
            layer=layer.id,
            tilematrixset="WebMercatorQuad",
            tilematrix=str(tile.z),
            row=tile.y,
            column=tile.x,
            format="image/png",
        )
        pixels = _png(response.read())
        assert (pixels[..., 3] == 255).sum() > 1000


def test_cog_reads_remotely_through_vsicurl_with_range_requests(
    compared_app: FastAPI, token: str, ids: dict
) -> None:
    with TestClient(compared_app) as client:
        products = client.get(
            f"/api/v1/sites/{ids['site']}/comparisons/{ids['comparison']}/products",
            headers={"Authorization": f"Bearer {token}"},
        ).json()
    dh = next(p for p in products if p["kind"] == "dh")
    with LiveServer(compared_app) as server:
        url = f"/vsicurl/{server.url}{dh['download_url']}?api_key={token}"
        with rasterio.Env(GDAL_DISABLE_READDIR_ON_OPEN="EMPTY_DIR"), rasterio.open(url) as src:
            assert src.crs.to_epsg() == 32632
            window = src.read(1, window=((100, 110), (100, 110)))
            assert window.shape == (10, 10)


def test_stac_catalog_walks_to_items_with_cog_assets(
    client: TestClient, auth: dict, ids: dict
) -> None:
    catalog = client.get("/stac/catalog.json", headers=auth).json()
    pystac.Catalog.from_dict(catalog)
    child = next(link["href"] for link in catalog["links"] if link["rel"] == "child")
    collection = client.get(child, headers=auth).json()
    pystac.Collection.from_dict(collection)
    items = [link["href"] for link in collection["links"] if link["rel"] == "item"]
    assert len(items) == 3  # two surveys and the comparison
    survey = pystac.Item.from_dict(client.get(items[0], headers=auth).json())
    assert survey.properties["proj:code"] == "EPSG:32632"
    assert survey.assets["dsm"].media_type == pystac.MediaType.COG
    partial = client.get(survey.assets["dsm"].href, headers={**auth, "Range": "bytes=0-3"})
    assert partial.status_code == 206 and partial.content in (b"II*\x00", b"MM\x00*")
    comparison = pystac.Item.from_dict(client.get(items[2], headers=auth).json())
    assert {"dh", "significance", "post_coregistered", "detections"} <= set(comparison.assets)
    assert comparison.properties["proj:code"] == "EPSG:32632"
    assert comparison.properties["slidewatch:detections"] == 1

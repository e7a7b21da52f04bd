"""The built map is served at `/`, its files under `/assets`; what it needs before sign-in
is public; API paths keep their own answers."""

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.config import Settings


@pytest.fixture
def built_map(tmp_path: Path) -> Path:
    dist = tmp_path / "dist"
    (dist / "assets").mkdir(parents=True)
    (dist / "index.html").write_text('<!doctype html><script src="./assets/map-1.js"></script>')
    (dist / "assets" / "map-1.js").write_text("console.log('map')")
    return dist


def client_for(settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(settings)) as client:
        yield client


@pytest.fixture
def map_client(embedded_settings: Settings, built_map: Path, app) -> Iterator[TestClient]:
    yield from client_for(embedded_settings.model_copy(update={"frontend_dir": built_map}))


def test_the_map_and_its_assets_are_served(map_client: TestClient) -> None:
    page = map_client.get("/")
    assert page.status_code == 200 and "assets/map-1.js" in page.text
    assert page.headers["cache-control"] == "no-cache"
    asset = map_client.get("/assets/map-1.js")
    assert asset.status_code == 200 and "console.log" in asset.text
    assert map_client.get("/assets/../index.html").status_code == 404


def test_api_paths_are_not_shadowed_by_the_map(map_client: TestClient) -> None:
    # GDAL asks HEAD before GET: the router's 405 must reach it, not a 404 from the map.
    assert map_client.head("/api/v1/sites").status_code == 405
    assert map_client.get("/api/v1/no-such-thing").status_code == 404
    assert map_client.get("/health").json() == {"status": "ok"}
    assert map_client.get("/docs").status_code == 200


def test_what_the_map_needs_first_is_public(map_client: TestClient) -> None:
    config = map_client.get("/app-config.json").json()
    assert config["basemap_url"] is None  # offline by default
    assert config["upload_chunk_bytes"] == 8 * 1024**2
    assert config["max_upload_bytes"] > 0


def test_a_map_that_is_not_built_says_how_to_build_it(
    embedded_settings: Settings, tmp_path: Path, app
) -> None:
    settings = embedded_settings.model_copy(update={"frontend_dir": tmp_path / "nothing"})
    for client in client_for(settings):
        page = client.get("/")
        assert page.status_code == 200 and "npm run build" in page.text


def test_a_basemap_is_a_setting(embedded_settings: Settings, app) -> None:
    url = "https://tile.openstreetmap.org/{z}/{x}/{y}.png"
    for client in client_for(embedded_settings.model_copy(update={"basemap_url": url})):
        assert client.get("/app-config.json").json()["basemap_url"] == url

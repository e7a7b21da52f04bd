"""Map tiles are cached and revalidated, a replaced product is never served from the cache,
and what one tile may read and how long it may take are bounded.

On the embedded default with one uploaded survey (its DSM is made a COG on upload; no
comparison job is needed): a few seconds."""

from __future__ import annotations

import asyncio
import io
import os
import socket
import time
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from types import SimpleNamespace
from unittest.mock import patch

import morecantile
import numpy as np
import pytest
import rasterio
from fastapi import FastAPI, HTTPException
from fastapi.testclient import TestClient
from PIL import Image
from rio_tiler.models import ImageData
from sqlalchemy import select, update
from uvicorn.protocols.http.auto import AutoHTTPProtocol

from backend.api.http_protocol import NoDelayHTTPProtocol
from backend.api.tile_grants import TileGrants
from backend.config import Settings
from backend.db.models import ApiToken, Product
from backend.db.tokens import hash_token
from backend.services import tiles as tiles_module
from backend.services.tile_cache import (
    DiskTileCache,
    FileIdentity,
    TileCache,
    TileKey,
    etag_matches,
    file_identity,
)
from backend.services.tile_prerender import bounded_levels, level_tiles
from backend.services.tiles import (
    SURVEY_LAYERS,
    LayerInfo,
    default_rescale,
    encode_rgba_png,
    known_default_rescale,
    raster_stats,
    stored_default_rescale,
    tile_read_pixels,
)
from tests.api_helpers import upload_dsm
from tests.monitoring_helpers import app_for, token_for
from worker.simulator.dsm_pair import DsmPairPaths

TMS = morecantile.tms.get("WebMercatorQuad")


@pytest.fixture(scope="module")
def surveyed(
    tmp_path_factory: pytest.TempPathFactory, gis_pair: DsmPairPaths
) -> Iterator[tuple[FastAPI, str]]:
    settings = Settings(data_dir=tmp_path_factory.mktemp("tile-cache") / "data")
    with pytest.MonkeyPatch.context() as monkeypatch, app_for(settings, monkeypatch) as app:
        with TestClient(app) as client:
            auth = {"Authorization": f"Bearer {token_for(app)}"}
            site = client.post("/api/v1/sites", json={"name": "cache"}, headers=auth)
            site_id = site.json()["id"]
            survey = upload_dsm(client, auth, site_id, gis_pair.pre, "2026-06-01T10:00:00Z")
        yield app, f"/api/v1/sites/{site_id}/surveys/{survey['id']}/tiles/dsm"


@pytest.fixture
def app(surveyed: tuple[FastAPI, str]) -> Iterator[FastAPI]:
    application = surveyed[0]
    settings = application.state.settings
    saved = settings.model_copy()
    yield application
    # Each test may tighten a limit or empty the cache; the next starts as configured.
    for name in ("tile_max_read_pixels", "tile_timeout_s"):
        setattr(settings, name, getattr(saved, name))


@pytest.fixture
def layer(surveyed: tuple[FastAPI, str]) -> str:
    return surveyed[1]


@pytest.fixture
def client(app: FastAPI) -> Iterator[TestClient]:
    with TestClient(app) as test_client:
        yield test_client


@pytest.fixture
def auth(app: FastAPI) -> dict[str, str]:
    return {"Authorization": f"Bearer {token_for(app)}"}


def _tile(client: TestClient, auth: dict, layer: str, zoom_out: int = 2) -> str:
    tilejson = client.get(f"{layer}/tilejson.json", headers=auth).json()
    west, south, east, north = tilejson["bounds"]
    tile = TMS.tile((west + east) / 2, (south + north) / 2, tilejson["maxzoom"] - zoom_out)
    return f"{layer}/{tile.z}/{tile.x}/{tile.y}.png"


def _product_path(app: FastAPI) -> Path:
    with app.state.sessionmaker() as session:
        product = session.scalar(select(Product).where(Product.kind == "dsm"))
        return app.state.storage.absolute(product.file.path)


def test_a_tile_asked_again_comes_from_the_cache_and_a_browser_gets_304(
    app: FastAPI, client: TestClient, auth: dict, layer: str
) -> None:
    url = _tile(client, auth, layer) + "?colormap=viridis"  # a style no other test asks for
    first = client.get(url, headers=auth)
    assert first.status_code == 200 and first.headers["x-tile-cache"] == "miss"
    assert first.headers["cache-control"] == "private, max-age=60"
    etag = first.headers["etag"]
    cache = app.state.tile_cache
    hits = cache.hits
    second = client.get(url, headers=auth)
    assert second.headers["x-tile-cache"] == "hit" and cache.hits == hits + 1
    assert second.content == first.content and second.headers["etag"] == etag
    # What a browser sends once its copy is older than max-age: 304, nothing rendered.
    misses = cache.misses
    revalidated = client.get(url, headers={**auth, "If-None-Match": etag})
    assert revalidated.status_code == 304 and revalidated.content == b""
    assert revalidated.headers["etag"] == etag and cache.misses == misses
    # The token is checked before the cache answers.
    assert client.get(url, headers={"If-None-Match": etag}).status_code == 401
    # Another style is another tile.
    other = client.get(url.replace("viridis", "magma"), headers=auth)
    assert other.headers["x-tile-cache"] == "miss" and other.headers["etag"] != etag


def test_the_api_processes_share_tiles_through_the_disk_cache(
    app: FastAPI, client: TestClient, auth: dict, layer: str
) -> None:
    url = _tile(client, auth, layer) + "?colormap=cividis"
    first = client.get(url, headers=auth)
    assert first.headers["x-tile-cache"] == "miss"
    # Another process has its own memory but the same folder: as one freshly started.
    del app.state.tile_cache
    again = client.get(url, headers=auth)
    assert again.headers["x-tile-cache"] == "hit" and again.content == first.content
    assert app.state.tile_cache.disk_hits == 1


def test_a_replaced_product_is_rendered_anew(
    app: FastAPI, client: TestClient, auth: dict, layer: str
) -> None:
    url = _tile(client, auth, layer)
    first = client.get(url, headers=auth)
    assert first.status_code == 200
    path = _product_path(app)
    replacement = path.with_suffix(".new.tif")
    with rasterio.open(path) as src:
        profile = src.profile
        data = src.read(1)
    # The same DSM upside down: another picture within the same stretch.
    profile.update(driver="GTiff")
    with rasterio.open(replacement, "w", **profile) as out:
        out.write(data[::-1], 1)
    os.replace(replacement, path)  # as a rerun stores a product: a new file in its place
    second = client.get(url, headers={**auth, "If-None-Match": first.headers["etag"]})
    assert second.status_code == 200 and second.headers["x-tile-cache"] == "miss"
    assert second.headers["etag"] != first.headers["etag"]
    before = np.asarray(Image.open(io.BytesIO(first.content)).convert("RGBA"))
    after = np.asarray(Image.open(io.BytesIO(second.content)).convert("RGBA"))
    assert not np.array_equal(before, after)


def test_the_default_stretch_asked_by_its_numbers_is_the_same_tile(
    client: TestClient, auth: dict, layer: str
) -> None:
    """The page asks for the DSM in the stretch TileJSON gives (to the mm), a GIS for no
    stretch: one tile, rendered (or rendered ahead) once."""
    url = _tile(client, auth, layer, zoom_out=1)
    low, high = client.get(f"{layer}/tilejson.json", headers=auth).json()["rescale"]
    assert (round(low, 3), round(high, 3)) == (low, high) and low < high
    plain = client.get(url, headers=auth)
    assert plain.status_code == 200 and plain.headers["x-tile-cache"] == "miss"
    page = client.get(f"{url}?rescale={low:.3f},{high:.3f}", headers=auth)
    assert page.headers["x-tile-cache"] == "hit" and page.content == plain.content
    assert page.headers["etag"] == plain.headers["etag"]
    other = client.get(f"{url}?rescale={low:.3f},{high + 1:.3f}", headers=auth)
    assert other.headers["x-tile-cache"] == "miss" and other.content != plain.content


def test_a_revoked_token_opens_tiles_no_longer_than_the_grants_lifetime(
    app: FastAPI, client: TestClient, layer: str
) -> None:
    """A check that passed is kept SLIDEWATCH_TILE_GRANT_TTL_S (5 s by default) per API
    process, so a map's tiles skip the database; a revocation holds once it runs out."""
    assert Settings().tile_grant_ttl_s == 5.0
    saved = getattr(app.state, "tile_grants", None)
    try:
        for ttl_s in (0.4, 0.0):
            app.state.tile_grants = TileGrants(ttl_s)
            own = {"Authorization": f"Bearer {token_for(app)}"}
            url = _tile(client, own, layer)
            assert client.get(url, headers=own).status_code == 200
            with app.state.sessionmaker() as session:
                session.execute(
                    update(ApiToken)
                    .where(ApiToken.token_hash == hash_token(own["Authorization"][7:]))
                    .values(revoked_at=datetime.now(UTC))
                )
                session.commit()
            if ttl_s:
                assert client.get(url, headers=own).status_code == 200  # still granted
                time.sleep(ttl_s + 0.1)
            refused = client.get(url, headers=own)
            assert refused.status_code == 401, ttl_s
            assert refused.json()["detail"] == "invalid or revoked API token"
    finally:
        app.state.tile_grants = saved


def test_grants_are_bounded_and_a_refusal_is_never_kept() -> None:
    grants: TileGrants[str] = TileGrants(60.0, max_entries=2)
    for key in ("a", "b", "c"):
        grants.put(key, key.upper())
    assert [grants.get(key) for key in ("a", "b", "c")] == [None, "B", "C"]

    def refuse() -> str:
        raise HTTPException(403, "no")

    with pytest.raises(HTTPException):
        asyncio.run(grants.resolve("d", refuse))
    assert grants.get("d") is None
    assert asyncio.run(grants.resolve("d", lambda: "D")) == "D" and grants.get("d") == "D"


def test_requests_for_one_layer_at_once_wait_for_one_check() -> None:
    """A map opening asks a dozen tiles of a layer at once: one check, not a dozen."""
    grants: TileGrants[str] = TileGrants(60.0)
    checks = []

    def check() -> str:
        checks.append(1)
        time.sleep(0.05)
        return "granted"

    async def twelve_at_once() -> list[str]:
        return await asyncio.gather(*(grants.resolve("layer", check) for _ in range(12)))

    assert asyncio.run(twelve_at_once()) == ["granted"] * 12 and len(checks) == 1

    def refuse() -> str:
        checks.append(1)
        time.sleep(0.05)
        raise HTTPException(403, "no")

    async def refused_at_once() -> list[object]:
        calls = (grants.resolve("other", refuse) for _ in range(5))
        return await asyncio.gather(*calls, return_exceptions=True)

    answers = asyncio.run(refused_at_once())
    assert all(isinstance(a, HTTPException) and a.status_code == 403 for a in answers)
    assert len(checks) == 2 and grants.get("other") is None


def test_a_tile_that_would_read_too_much_is_refused(
    app: FastAPI, client: TestClient, auth: dict, layer: str
) -> None:
    url = _tile(client, auth, layer, zoom_out=0) + "?colormap=plasma"
    app.state.settings.tile_max_read_pixels = 100
    refused = client.get(url, headers=auth)
    assert refused.status_code == 422
    assert "SLIDEWATCH_TILE_MAX_READ_PIXELS" in refused.json()["detail"]


def test_a_tile_that_takes_too_long_is_answered_503(
    app: FastAPI, client: TestClient, auth: dict, layer: str
) -> None:
    url = _tile(client, auth, layer) + "?colormap=inferno"
    app.state.settings.tile_timeout_s = 1e-9
    late = client.get(url, headers=auth)
    assert late.status_code == 503 and "SLIDEWATCH_TILE_TIMEOUT_S" in late.json()["detail"]
    assert late.headers["retry-after"]


def _plain_tiff(path: Path, side: int, overviews: bool) -> Path:
    """A float DSM of `side`² pixels, tiled, with or without overviews."""
    transform = rasterio.transform.from_origin(500000, 5100000, 0.5, 0.5)
    data = np.add.outer(np.arange(side), np.arange(side)).astype("float32")
    with rasterio.open(
        path, "w", driver="GTiff", width=side, height=side, count=1, dtype="float32",
        crs="EPSG:32632", transform=transform, tiled=True, nodata=-9999,
    ) as out:  # fmt: skip
        out.write(data, 1)
        if overviews:
            out.build_overviews([2, 4, 8, 16])
    return path


def test_a_tile_read_is_bounded_by_overviews_and_its_footprint(tmp_path: Path) -> None:
    with_overviews = _plain_tiff(tmp_path / "cog.tif", 2048, overviews=True)
    without = _plain_tiff(tmp_path / "plain.tif", 2048, overviews=False)
    with rasterio.open(with_overviews) as cog, rasterio.open(without) as plain:
        west, south, east, north = rasterio.warp.transform_bounds(cog.crs, "EPSG:4326", *cog.bounds)
        near = TMS.tile((west + east) / 2, (south + north) / 2, 20)
        far = TMS.tile((west + east) / 2, (south + north) / 2, 12)
        # Near: about a tile's worth of pixels either way.
        assert tile_read_pixels(plain, near.z, near.x, near.y) < 4 * 256**2
        # Far out the whole file falls in the tile: all of it without overviews, the
        # coarsest overview with them.
        assert tile_read_pixels(plain, far.z, far.x, far.y) == 2048**2
        assert tile_read_pixels(cog, far.z, far.x, far.y) <= (2048 // 16) ** 2
    # The default stretch of a file without overviews reads a bounded window, not all of it.
    stats = raster_stats(without, max_read_pixels=256**2)
    assert np.isfinite([stats.p2, stats.p98]).all() and stats.p98 - stats.p2 < 512
    assert raster_stats(without).p98 - raster_stats(without).p2 > 3000


def test_a_default_stretch_is_read_once_and_noted_beside_the_tiles(tmp_path: Path) -> None:
    dsm = _plain_tiff(tmp_path / "dsm.tif", 512, overviews=True)
    disk = DiskTileCache(tmp_path / "tiles", max_bytes=10_000)
    spec = SURVEY_LAYERS["dsm"]
    stretch = stored_default_rescale(disk, "surveys/1", spec, dsm)
    assert stretch == default_rescale(spec, dsm) and stretch[0] < stretch[1]
    [note] = (tmp_path / "tiles").glob("surveys-1/*/stretch-dsm-*.json")
    # A process that starts takes the note, not the raster.
    note.write_text("[1.5, 2.5]")
    tiles_module._STRETCHES.clear()
    assert stored_default_rescale(disk, "surveys/1", spec, dsm) == (1.5, 2.5)
    assert known_default_rescale(spec, file_identity(dsm)) == (1.5, 2.5)
    disk.forget_groups(["surveys/1"])
    tiles_module._STRETCHES.clear()
    assert stored_default_rescale(disk, "surveys/1", spec, dsm) == stretch


def _key(z: int) -> TileKey:
    return TileKey(FileIdentity("/x.tif", 1, 2, 3, 4), "dsm/elevation", z, 0, 0, None, None)


def test_the_cache_is_bounded_in_bytes_and_forgets_what_was_used_longest_ago(
    tmp_path: Path,
) -> None:
    cache = TileCache(max_bytes=250)
    for z in range(3):
        cache.put(_key(z), bytes(100))
    assert len(cache) == 2 and cache.size_bytes == 200 and cache.get(_key(0)) is None
    cache.get(_key(1))
    cache.put(_key(3), bytes(100))  # evicts 2, used longer ago than 1
    assert cache.get(_key(1)) is not None and cache.get(_key(2)) is None
    disk = DiskTileCache(tmp_path / "tiles", max_bytes=1000)
    for z in range(30):
        disk.put(_key(z), bytes(100))
    kept = sum(p.stat().st_size for p in (tmp_path / "tiles").glob("*/*/*.png"))
    assert kept <= 1000 + 100 * 2 and disk.get(_key(29)) == bytes(100)
    assert TileCache(max_bytes=0).get(_key(0)) is None


def test_a_groups_tiles_on_disk_go_with_it_or_with_the_file_they_were_made_from(
    tmp_path: Path,
) -> None:
    disk = DiskTileCache(tmp_path / "tiles", max_bytes=10_000)
    old_file = FileIdentity("/dh.tif", 1, 2, 3, 4)
    new_file = FileIdentity("/dh.tif", 1, 5, 3, 6)  # the same path written anew
    keys = {
        (file, group): TileKey(file, "dh/difference", 18, 1, 1, None, None, group)
        for file in (old_file, new_file)
        for group in ("comparisons/1", "comparisons/2")
    }
    for key in keys.values():
        disk.put(key, b"png")
    assert all(disk.contains(key) for key in keys.values())
    assert disk.keep_only("comparisons/1", {new_file}) == 1
    assert not disk.contains(keys[(old_file, "comparisons/1")])
    assert disk.contains(keys[(new_file, "comparisons/1")])
    assert disk.contains(keys[(old_file, "comparisons/2")])
    disk.forget_groups(["comparisons/2"])
    assert not disk.contains(keys[(old_file, "comparisons/2")])
    assert not disk.contains(keys[(new_file, "comparisons/2")])
    assert disk.get(keys[(new_file, "comparisons/1")]) == b"png"


def test_colour_tiles_are_encoded_as_rio_tiler_draws_them() -> None:
    rng = np.random.default_rng(3)
    data = rng.integers(0, 256, size=(3, 256, 256), dtype=np.uint8)
    mask = np.zeros((3, 256, 256), dtype=bool)
    mask[:, :40, :] = True  # outside the orthophoto: transparent
    img = ImageData(np.ma.MaskedArray(data, mask=mask))
    ours = Image.open(io.BytesIO(encode_rgba_png(img)))
    theirs = Image.open(io.BytesIO(img.render(img_format="PNG")))
    assert ours.mode == "RGBA"
    assert np.array_equal(np.asarray(ours), np.asarray(theirs.convert("RGBA")))
    assert (np.asarray(ours)[:40, :, 3] == 0).all() and (np.asarray(ours)[40:, :, 3] == 255).all()


def test_the_tiles_rendered_ahead_stop_at_the_level_that_would_pass_the_bound() -> None:
    info = LayerInfo((9.0, 46.049, 9.0065, 46.0536), minzoom=16, maxzoom=21)
    counts = [len(level_tiles(info, z)) for z in range(16, 22)]
    assert counts == sorted(counts) and counts[-1] > 1000
    levels = bounded_levels(info, max_tiles=sum(counts[:4]) + counts[4] - 1)
    assert [z for z, _ in levels] == [16, 17, 18, 19]
    assert [len(tiles) for _, tiles in levels] == counts[:4]
    assert len(bounded_levels(info, max_tiles=sum(counts))) == 6
    assert bounded_levels(info, max_tiles=0) == []


def test_if_none_match_lists_and_weak_validators() -> None:
    etag = _key(1).etag
    assert etag_matches(f'"other", W/{etag}', etag) and etag_matches("*", etag)
    assert not etag_matches('"other"', etag) and not etag_matches(None, etag)
    assert _key(1).etag != _key(2).etag


def test_the_api_runs_a_process_per_core_by_default() -> None:
    cores = len(os.sched_getaffinity(0))
    assert Settings().resolved_api_workers == max(1, min(cores, 4))
    assert Settings(api_workers=3).resolved_api_workers == 3
    assert SURVEY_LAYERS["dsm"].default_colormap == "terrain"


def test_every_connection_of_the_api_is_sent_without_delay() -> None:
    """With several processes uvicorn's listening socket leaves Nagle's algorithm on; the
    API's protocol turns it off for each connection (an answer waited 40 ms otherwise)."""
    listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM, 0)  # as uvicorn binds it
    listener.bind(("127.0.0.1", 0))
    listener.listen()
    with listener, socket.create_connection(listener.getsockname()) as _client:
        accepted, _ = listener.accept()
        with accepted:
            assert accepted.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) == 0
            transport = SimpleNamespace(get_extra_info=lambda name: accepted)
            protocol = NoDelayHTTPProtocol.__new__(NoDelayHTTPProtocol)
            with patch.object(AutoHTTPProtocol, "connection_made") as base:
                protocol.connection_made(transport)  # type: ignore[arg-type]
            base.assert_called_once()
            assert accepted.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) == 1

"""A real worker renders a survey's and a comparison's map tiles ahead, into the disk cache
the API reads: the first request of a tile is a cache hit with the very bytes a render
gives, and deleting the comparison or the survey removes its tiles (embedded default, a
small pair: seconds)."""

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from backend.config import Settings
from backend.db.session import make_engine
from backend.services.tile_cache import DiskTileCache
from backend.services.tile_prerender import PrerenderLayer, bounded_levels, prerender_layers
from backend.services.tiles import layer_info, render_tile, tile_key
from backend.storage import LocalStorage
from tests.integration.conftest import SlidewatchProcess, api_client, wait_for_job
from tests.integration.test_comparison_jobs import submit_comparison
from tests.monitoring_helpers import wait_until
from worker.simulator.dsm_pair import make_dsm_pair, write_dsm_pair

pytestmark = pytest.mark.integration


def _layers(settings: Settings, owner: str, owner_id: int) -> list[PrerenderLayer]:
    from sqlalchemy.orm import Session

    with Session(make_engine(settings.resolved_database_url)) as session:
        layers = prerender_layers(
            session, LocalStorage(settings.storage_dir), settings, owner, owner_id
        )
    assert layers is not None
    return layers


def _missing(disk: DiskTileCache, layer: PrerenderLayer) -> int:
    keys = (
        tile_key(layer.identity, layer.spec, t.z, t.x, t.y, layer.rescale, None, layer.group)
        for t in layer.tiles
    )
    return sum(not disk.contains(key) for key in keys)


def _logged_done(worker: SlidewatchProcess, prefix: str) -> bool:
    lines = worker.log_path.read_text(errors="replace").splitlines()
    return any(prefix in line and line.endswith(", done") for line in lines)


def test_a_worker_renders_the_tiles_ahead_and_deleting_removes_them(
    tmp_path: Path,
    start_worker: Callable[..., SlidewatchProcess],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # As deployed: the setting's default (tests/conftest.py turns it off for the others).
    default = Settings.model_fields["tile_prerender_max_tiles"].default
    monkeypatch.setenv("SLIDEWATCH_TILE_PRERENDER_MAX_TILES", str(default))
    settings = Settings(data_dir=tmp_path / "data")
    assert settings.tile_prerender_max_tiles == default > 0
    client, auth = api_client(settings)
    worker = start_worker(settings)
    pair = make_dsm_pair(shape=(120, 120), pixel_size_m=2.0, shift_m=(2.6, -1.4, 0.2), seed=7)
    site, job_id = submit_comparison(client, auth, write_dsm_pair(pair, tmp_path))
    job = wait_for_job(client, auth, site, job_id, lambda j: j["state"] in ("succeeded", "failed"))
    assert job["state"] == "succeeded", job
    comparison = job["comparison_id"]
    pre, post = 1, 2
    for owner, owner_id in (("surveys", pre), ("surveys", post), ("comparisons", comparison)):
        done = f"tiles of {owner} {owner_id} rendered ahead"
        wait_until(lambda done=done: _logged_done(worker, done), timeout_s=120)

    disk = DiskTileCache(settings.tile_cache_dir, settings.tile_disk_cache_bytes)
    survey_layers = _layers(settings, "surveys", pre)
    comparison_layers = _layers(settings, "comparisons", comparison)
    assert [layer.spec.name for layer in survey_layers] == ["hillshade", "dsm"]
    assert [layer.spec.name for layer in comparison_layers] == ["dh", "hillshade", "dsm"]
    for layer in survey_layers + comparison_layers:
        # Every level from the whole site in one tile to the finest the map asks for: a
        # small site is far within the bound.
        info = layer_info(layer.path)
        assert layer.zooms == tuple(range(info.minzoom, info.maxzoom + 1))
        expected = bounded_levels(info, settings.tile_prerender_max_tiles)
        assert len(layer.tiles) == sum(len(tiles) for _, tiles in expected) > 10
        assert _missing(disk, layer) == 0, layer.spec.name

    # The first request of a tile, with no style (a GIS) or with the page's stretch (from
    # TileJSON), is a hit: the bytes a fresh render gives.
    base = f"/api/v1/sites/{site}/comparisons/{comparison}/tiles/dh"
    dh = comparison_layers[0]
    tile = dh.tiles[len(dh.tiles) // 2]
    fresh = render_tile(dh.path, dh.spec, tile.z, tile.x, tile.y, dh.rescale)
    answer = client.get(f"{base}/{tile.z}/{tile.x}/{tile.y}.png", headers=auth)
    assert answer.status_code == 200 and answer.headers["x-tile-cache"] == "hit"
    assert answer.content == fresh
    low, high = client.get(f"{base}/tilejson.json", headers=auth).json()["rescale"]
    assert (low, high) == dh.rescale and low == -high
    # Noted beside the tiles: an API process that starts does not read the raster for it.
    [note] = (settings.tile_cache_dir / f"comparisons-{comparison}").glob("*/stretch-dh-*.json")
    assert tuple(json.loads(note.read_text())) == (low, high)
    page = client.get(
        f"{base}/{tile.z}/{tile.x}/{tile.y}.png?rescale={low:.3f},{high:.3f}", headers=auth
    )
    assert page.headers["x-tile-cache"] == "hit" and page.headers["etag"] == answer.headers["etag"]

    groups = settings.tile_cache_dir
    assert len(list((groups / f"comparisons-{comparison}").rglob("*.png"))) == sum(
        len(layer.tiles) for layer in comparison_layers
    )
    deleted = client.delete(f"/api/v1/sites/{site}/comparisons/{comparison}", headers=auth)
    assert deleted.status_code == 204
    assert not (groups / f"comparisons-{comparison}").exists()
    assert (groups / f"surveys-{pre}").exists()
    assert client.delete(f"/api/v1/sites/{site}/surveys/{pre}", headers=auth).status_code == 204
    assert not (groups / f"surveys-{pre}").exists() and (groups / f"surveys-{post}").exists()
    assert client.delete(f"/api/v1/sites/{site}", headers=auth).status_code == 204
    assert not any(groups.iterdir())

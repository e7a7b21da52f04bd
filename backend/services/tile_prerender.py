"""Map tiles rendered ahead: a product's tiles are in the shared disk cache before anyone
looks at them, so that the first visit is answered as fast as the second.

Once a survey is ready (its DSM uploaded, or its reconstruction finished) or a comparison
has succeeded, a worker renders the layers the page shows by default, and those a GIS asks
for, into the disk cache the API reads (backend/services/tile_cache.py), with the keys the
API's own requests have (`tile_key`, the default stretch resolved), so that a request is a
disk hit:

    survey      orthophoto, hillshade, dsm
    comparison  dh, the post survey's orthophoto moved by its co-registration, hillshade, dsm

For each layer the zoom levels from the layer's coarsest (the whole site in a tile or
two) finer and finer, as long as the layer's tiles so far stay within
SLIDEWATCH_TILE_PRERENDER_MAX_TILES (a level that would pass it, and every finer one, is
left to be rendered on demand): the whole site at every level where it shows in a few
hundred tiles, the overview levels of a large one.

The work is done in chunks of a few seconds, each a task of its own
(`worker/tasks_tiles.py`), and a chunk gives way as soon as a job's stage waits to run: a
job's result never waits for tiles. Tiles already on disk are skipped, so a chunk run
twice costs a `stat` a tile; each tile is written to a temporary file and renamed.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import morecantile
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.config import Settings
from backend.db.models import Comparison, JobState, Product, StageRun, StageState, Survey
from backend.services.post_motion import PostMotion, motion_from_summary
from backend.services.tile_cache import DiskTileCache, FileIdentity, file_identity, group_name
from backend.services.tiles import (
    COMPARISON_LAYERS,
    SURVEY_LAYERS,
    TMS,
    LayerInfo,
    LayerSpec,
    TileOutsideBounds,
    TileTooCostly,
    is_geotiff,
    layer_info,
    render_tile,
    stored_default_rescale,
    stretched,
    tile_key,
)
from backend.storage import LocalStorage

log = logging.getLogger(__name__)

OWNERS = ("surveys", "comparisons")
# How long one chunk renders before the rest is queued as a task of its own, and how often
# it looks whether a job's stage waits meanwhile.
CHUNK_S = 5.0
YIELD_CHECK_S = 1.0


@dataclass(frozen=True)
class PrerenderLayer:
    """One layer to render ahead: its file, style and the tiles of its bounded levels."""

    group: str
    spec: LayerSpec
    path: Path
    identity: FileIdentity
    rescale: tuple[float, float] | None
    motion: PostMotion | None
    zooms: tuple[int, ...]
    tiles: tuple[morecantile.Tile, ...] = field(repr=False)


def level_tiles(info: LayerInfo, z: int) -> list[morecantile.Tile]:
    """The tiles of zoom `z` over the layer's bounds, as the map asks for them."""
    west, south, east, north = info.bounds
    return list(TMS.tiles(west, south, east, north, [z]))


def bounded_levels(info: LayerInfo, max_tiles: int) -> list[tuple[int, list[morecantile.Tile]]]:
    """The layer's levels from its coarsest down, while their tiles together stay within
    `max_tiles`; the first level that would pass it ends the list."""
    levels = []
    total = 0
    for z in range(info.minzoom, info.maxzoom + 1):
        tiles = level_tiles(info, z)
        if total + len(tiles) > max_tiles:
            break
        total += len(tiles)
        levels.append((z, tiles))
    return levels


def _product_path(
    session: Session, storage: LocalStorage, owner: str, owner_id: int, kind: str
) -> Path | None:
    column = Product.survey_id if owner == "surveys" else Product.comparison_id
    product = session.scalar(select(Product).where(column == owner_id, Product.kind == kind))
    if product is None:
        return None
    path = storage.absolute(product.file.path)
    return path if path.is_file() and is_geotiff(path) else None


def _layer(
    settings: Settings,
    group: str,
    spec: LayerSpec,
    path: Path,
    motion: PostMotion | None = None,
) -> PrerenderLayer:
    info = layer_info(path)
    levels = bounded_levels(info, settings.tile_prerender_max_tiles)
    rescale = (
        stored_default_rescale(
            _disk_cache(settings), group, spec, path, settings.tile_max_read_pixels
        )
        if stretched(spec)
        else None
    )
    return PrerenderLayer(
        group=group,
        spec=spec,
        path=path,
        identity=file_identity(path),
        rescale=rescale,
        motion=motion,
        zooms=tuple(z for z, _ in levels),
        tiles=tuple(tile for _, tiles in levels for tile in tiles),
    )


def prerender_layers(
    session: Session, storage: LocalStorage, settings: Settings, owner: str, owner_id: int
) -> list[PrerenderLayer] | None:
    """The layers of a survey or a comparison to render ahead, in the order the page shows
    them; None when it is gone (or a comparison not succeeded)."""
    group = group_name(owner, owner_id)
    layers: list[PrerenderLayer] = []
    if owner == "surveys":
        if session.get(Survey, owner_id) is None:
            return None
        specs = [SURVEY_LAYERS[name] for name in ("orthophoto", "hillshade", "dsm")]
    else:
        comparison = session.get(Comparison, owner_id)
        if comparison is None or comparison.status != JobState.succeeded:
            return None
        specs = [COMPARISON_LAYERS[name] for name in ("dh", "hillshade", "dsm")]
        motion = motion_from_summary(comparison.summary)
        orthophoto = _product_path(
            session, storage, "surveys", comparison.post_survey_id, "orthophoto"
        )
        if motion and orthophoto is not None:
            # The page draws the post survey's orthophoto where the comparison put it.
            layers.append(_layer(settings, group, SURVEY_LAYERS["orthophoto"], orthophoto, motion))
    for spec in specs:
        path = _product_path(session, storage, owner, owner_id, spec.product_kind)
        if path is not None:
            layers.append(_layer(settings, group, spec, path))
    order = {"orthophoto": 0, "dh": 0, "hillshade": 1, "dsm": 2}
    return sorted(layers, key=lambda layer: order[layer.spec.name])


_disk_caches: dict[tuple[Path, int], DiskTileCache] = {}


def _disk_cache(settings: Settings) -> DiskTileCache:
    """One per folder in a process, as the API has: it prunes the folder once it has
    written a tenth of its bound, not at every chunk's first tile."""
    key = (settings.tile_cache_dir, settings.tile_disk_cache_bytes)
    if key not in _disk_caches:
        _disk_caches[key] = DiskTileCache(*key)
    return _disk_caches[key]


def a_stage_waits(session: Session) -> bool:
    """Whether a job's stage has been queued and not yet taken by a worker."""
    waiting = select(StageRun.id).where(
        StageRun.state == StageState.pending, StageRun.queued_at.is_not(None)
    )
    return session.scalar(waiting.limit(1)) is not None


@dataclass
class ChunkResult:
    rendered: int = 0
    present: int = 0  # already on disk
    refused: int = 0  # outside the layer, or too costly to read
    total: int = 0
    next_start: int | None = None  # where the next chunk begins; None: done
    gone: bool = False  # the survey or comparison is no longer there (or not succeeded)
    layers: list[PrerenderLayer] = field(default_factory=list)

    @property
    def done(self) -> int:
        return self.total if self.next_start is None else self.next_start


def prerender_chunk(
    session: Session,
    storage: LocalStorage,
    settings: Settings,
    owner: str,
    owner_id: int,
    start: int = 0,
    budget_s: float = CHUNK_S,
) -> ChunkResult:
    """Render the tiles `start`, `start + 1` … of the owner's layers into the disk cache
    for about `budget_s` seconds, or until a job's stage waits; say where to go on."""
    if owner not in OWNERS:
        raise ValueError(f"tiles are rendered ahead for {', '.join(OWNERS)}, not {owner!r}")
    result = ChunkResult()
    disk = _disk_cache(settings)
    group = group_name(owner, owner_id)
    layers = prerender_layers(session, storage, settings, owner, owner_id)
    session.commit()  # no transaction held open while rendering
    if layers is None:
        result.gone = True
        disk.forget_groups([group])
        return result
    result.layers = layers
    if start == 0:
        # Tiles of files this owner no longer shows (a product replaced by a new file).
        disk.keep_only(group, {layer.identity for layer in layers})
    work = [(layer, tile) for layer in layers for tile in layer.tiles]
    result.total = len(work)
    started = time.monotonic()
    last_check = started - YIELD_CHECK_S  # looked at before the first tile too
    position = start
    while position < len(work):
        now = time.monotonic()
        if now - started > budget_s:
            break
        if now - last_check >= YIELD_CHECK_S:
            last_check = now
            waits = a_stage_waits(session)
            session.commit()
            if waits:
                break
        layer, tile = work[position]
        position += 1
        key = tile_key(
            layer.identity, layer.spec, tile.z, tile.x, tile.y, layer.rescale, None,
            layer.group, layer.motion,
        )  # fmt: skip
        if disk.contains(key):
            result.present += 1
            continue
        try:
            png = render_tile(
                layer.path, layer.spec, tile.z, tile.x, tile.y, layer.rescale, None,
                max_read_pixels=settings.tile_max_read_pixels, motion=layer.motion,
            )  # fmt: skip
        except (TileOutsideBounds, TileTooCostly):
            result.refused += 1
            continue
        disk.put(key, png)
        result.rendered += 1
    result.next_start = position if position < len(work) else None
    return result


def describe(owner: str, owner_id: int, layers: list[PrerenderLayer]) -> str:
    """One line on what is rendered ahead: each layer's levels and tiles."""
    parts = [
        f"{layer.spec.name}{'@moved' if layer.motion else ''} z{layer.zooms[0]}-{layer.zooms[-1]} "
        f"({len(layer.tiles)} tiles)"
        for layer in layers
        if layer.zooms
    ]
    return f"{owner[:-1]} {owner_id}: " + (", ".join(parts) or "no layer")

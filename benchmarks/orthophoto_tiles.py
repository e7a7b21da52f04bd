"""What an orthophoto map tile costs to encode: rio-tiler's PNG (GDAL, zlib level 6) against
the one the API serves (OpenCV, zlib level 1, runs only), over the tiles of an
orthophoto, with the pixels checked equal.

    .venv/bin/python benchmarks/orthophoto_tiles.py ORTHOPHOTO.tif [--zooms 2]

ORTHOPHOTO.tif: an RGBA orthophoto (what the orthophoto stage writes); it is made a COG
first, as a survey's product is. The tiles are those of the finest `--zooms` levels the
layer's TileJSON offers, as the map asks for them.
"""

from __future__ import annotations

import argparse
import io
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image
from rio_tiler.io import Reader

from backend.services.tiles import TMS, encode_rgba_png, layer_info
from worker.pipeline.cog import RasterRole, write_cog


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("orthophoto", type=Path)
    parser.add_argument("--zooms", type=int, default=2, help="finest levels to take tiles of")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        cog = Path(folder) / "orthophoto.cog.tif"
        write_cog(args.orthophoto, cog, RasterRole.image)
        info = layer_info(cog)
        west, south, east, north = info.bounds
        zooms = list(range(info.maxzoom - args.zooms + 1, info.maxzoom + 1))
        tiles = list(TMS.tiles(west, south, east, north, zooms))
        images = []
        with Reader(str(cog), tms=TMS) as reader:
            for tile in tiles:
                if not reader.tile_exists(tile.x, tile.y, tile.z):
                    continue  # touches the layer's bounds only: the API answers 404
                img = reader.tile(
                    tile.x, tile.y, tile.z, tilesize=256,
                    resampling_method="bilinear", reproject_method="bilinear",
                )  # fmt: skip
                images.append(img)
    figures = {}
    for img in images[:10]:  # each encoder's first calls load and set it up: not measured
        img.render(img_format="PNG")
        encode_rgba_png(img)
    for name, encode in (
        ("rio-tiler render (GDAL, level 6)", lambda img: img.render(img_format="PNG")),
        ("OpenCV, level 1, runs only", encode_rgba_png),
    ):
        started = time.perf_counter()
        encoded = [encode(img) for img in images]
        seconds = time.perf_counter() - started
        figures[name] = encoded
        print(
            f"{name:<34} {seconds / len(images) * 1000:6.2f} ms a tile, "
            f"{np.mean([len(png) for png in encoded]) / 1024:6.1f} KiB a tile"
        )
    theirs, ours = figures.values()
    for a, b in zip(theirs, ours, strict=True):
        pixels_a = np.asarray(Image.open(io.BytesIO(a)).convert("RGBA"))
        pixels_b = np.asarray(Image.open(io.BytesIO(b)).convert("RGBA"))
        assert np.array_equal(pixels_a, pixels_b), "the encodings differ in their pixels"
    print(f"{len(images)} tiles of z{zooms[0]}-{zooms[-1]}, pixel for pixel the same")


if __name__ == "__main__":
    main()

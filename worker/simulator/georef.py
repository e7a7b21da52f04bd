"""Where a simulated scene lies on Earth, and the raster grid its truth lives on.

Scenes are built in a local metric frame (x east, y north, z up, metres) whose origin
is a whole-metre point of a UTM zone; heights are metres above the ellipsoid (the
simulator has no geoid, so "altitude above sea level" in its logs is the same number).
`SceneFrame` converts local coordinates to the projected CRS and to WGS84 lon/lat
for the flight logs; `Grid` is a north-up raster in local coordinates with the GDAL
convention (origin at the top-left corner of the top-left cell).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from affine import Affine
from pyproj import CRS, Transformer

WGS84 = "EPSG:4326"


@functools.lru_cache(maxsize=16)
def _transformer(src: str, dst: str) -> Transformer:
    return Transformer.from_crs(CRS.from_user_input(src), CRS.from_user_input(dst), always_xy=True)


def utm_epsg_for(lon: float, lat: float) -> str:
    """The EPSG code of the UTM zone that contains (lon, lat): 326zz north, 327zz south."""
    zone = int((lon + 180.0) // 6.0) % 60 + 1
    return f"EPSG:{32600 + zone if lat >= 0 else 32700 + zone}"


@dataclass(frozen=True)
class SceneFrame:
    """A local metric frame anchored at (origin_e, origin_n) of a projected CRS."""

    crs: str
    origin_e: float
    origin_n: float

    @classmethod
    def at_lonlat(cls, lon: float, lat: float, crs: str | None = None) -> SceneFrame:
        """A frame whose origin is the whole-metre UTM point nearest to (lon, lat)."""
        crs = crs or utm_epsg_for(lon, lat)
        e, n = _transformer(WGS84, crs).transform(lon, lat)
        return cls(crs=crs, origin_e=float(round(e)), origin_n=float(round(n)))

    def to_world(self, x, y):
        """Local (x, y) to projected (E, N)."""
        return np.asarray(x, dtype=np.float64) + self.origin_e, np.asarray(
            y, dtype=np.float64
        ) + self.origin_n

    def to_local(self, e, n):
        """Projected (E, N) to local (x, y)."""
        return np.asarray(e, dtype=np.float64) - self.origin_e, np.asarray(
            n, dtype=np.float64
        ) - self.origin_n

    def lonlat(self, x, y):
        """Local (x, y) to WGS84 (lon, lat) in degrees."""
        e, n = self.to_world(x, y)
        lon, lat = _transformer(self.crs, WGS84).transform(e, n)
        return np.asarray(lon), np.asarray(lat)

    def from_lonlat(self, lon, lat):
        """WGS84 (lon, lat) to local (x, y)."""
        e, n = _transformer(WGS84, self.crs).transform(
            np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64)
        )
        return self.to_local(e, n)

    def to_dict(self) -> dict:
        lon, lat = self.lonlat(0.0, 0.0)
        return {
            "crs": self.crs,
            "origin_e": self.origin_e,
            "origin_n": self.origin_n,
            "origin_lon": round(float(lon), 8),
            "origin_lat": round(float(lat), 8),
            "heights": "metres above the WGS84 ellipsoid (no geoid in simulation)",
        }


@dataclass(frozen=True)
class Grid:
    """A north-up raster in local coordinates: cell (row, col) covers
    x in [x_left + col*res, x_left + (col+1)*res] and y in [y_top - (row+1)*res, y_top - row*res].
    """

    x_left: float
    y_top: float
    res: float
    width: int
    height: int

    @classmethod
    def centered(cls, width_m: float, height_m: float, res: float) -> Grid:
        """A grid of the given size centred on the local origin."""
        w = round(width_m / res)
        h = round(height_m / res)
        return cls(x_left=-w * res / 2.0, y_top=h * res / 2.0, res=res, width=w, height=h)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.height, self.width)

    @property
    def x_right(self) -> float:
        return self.x_left + self.width * self.res

    @property
    def y_bottom(self) -> float:
        return self.y_top - self.height * self.res

    @property
    def cell_area(self) -> float:
        return self.res * self.res

    def x_centers(self) -> np.ndarray:
        return self.x_left + (np.arange(self.width) + 0.5) * self.res

    def y_centers(self) -> np.ndarray:
        return self.y_top - (np.arange(self.height) + 0.5) * self.res

    def mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """Cell-centre coordinates (x, y), each of shape (height, width)."""
        return np.meshgrid(self.x_centers(), self.y_centers())

    def col_row(self, x, y):
        """Continuous (col, row) of local (x, y), with cell centres at integers."""
        col = (np.asarray(x) - self.x_left) / self.res - 0.5
        row = (self.y_top - np.asarray(y)) / self.res - 0.5
        return col, row

    def xy(self, row, col):
        """Local (x, y) of continuous (row, col) with cell centres at integers."""
        x = self.x_left + (np.asarray(col) + 0.5) * self.res
        y = self.y_top - (np.asarray(row) + 0.5) * self.res
        return x, y

    def window(self, x_min: float, y_min: float, x_max: float, y_max: float):
        """Row and column slices of the cells that intersect a local bounding box."""
        c0 = max(0, int(np.floor((x_min - self.x_left) / self.res)))
        c1 = min(self.width, int(np.ceil((x_max - self.x_left) / self.res)))
        r0 = max(0, int(np.floor((self.y_top - y_max) / self.res)))
        r1 = min(self.height, int(np.ceil((self.y_top - y_min) / self.res)))
        return slice(r0, max(r0, r1)), slice(c0, max(c0, c1))

    def sub(self, rows: slice, cols: slice) -> Grid:
        """The grid of a window."""
        return Grid(
            x_left=self.x_left + cols.start * self.res,
            y_top=self.y_top - rows.start * self.res,
            res=self.res,
            width=cols.stop - cols.start,
            height=rows.stop - rows.start,
        )

    def transform(self, frame: SceneFrame) -> Affine:
        """The GDAL geotransform of this grid in the frame's projected CRS."""
        e, n = frame.to_world(self.x_left, self.y_top)
        return Affine(self.res, 0.0, float(e), 0.0, -self.res, float(n))

    def to_dict(self, frame: SceneFrame) -> dict:
        e, n = frame.to_world(self.x_left, self.y_top)
        return {
            "width": self.width,
            "height": self.height,
            "res_m": self.res,
            "west": float(e),
            "north": float(n),
            "east": float(e) + self.width * self.res,
            "south": float(n) - self.height * self.res,
        }

"""Zone choice and RFC 7946 output geometry."""

import numpy as np
import pytest
import shapely
from rasterio.crs import CRS

from worker.pipeline.geo import (
    crs_to_string,
    is_metric_projected,
    pixel_size_m,
    to_wgs84_geojson,
    utm_epsg_for_lonlat,
)


@pytest.mark.parametrize(
    ("lon", "lat", "epsg"),
    [
        (9.5, 46.2, 32632),
        (6.0, 46.0, 32632),
        (5.999, 46.0, 32631),
        (-70.6, -33.4, 32719),
        (-180.0, 10.0, 32601),
        (180.0, 10.0, 32660),
        (139.7, 0.0, 32654),
        (10.0, 78.0, 32632),
    ],
)
def test_utm_zone_of_the_centroid_longitude(lon, lat, epsg):
    assert utm_epsg_for_lonlat(lon, lat) == epsg


def test_crs_helpers():
    assert crs_to_string(CRS.from_epsg(32632)) == "EPSG:32632"
    assert is_metric_projected(CRS.from_epsg(32632))
    assert not is_metric_projected(CRS.from_epsg(4326))
    assert not is_metric_projected(CRS.from_epsg(2230))  # US survey feet


def test_geographic_pixel_size_in_metres():
    from rasterio.transform import from_origin

    transform = from_origin(9.0, 46.0, 1e-5, 1e-5)
    dx, dy = pixel_size_m(transform, CRS.from_epsg(4326), (100, 100))
    assert dx == pytest.approx(0.7746, rel=1e-3)  # geodesic on WGS84 at 46 N
    assert dy == pytest.approx(1.1115, rel=1e-3)


def test_geojson_is_rfc7946_ccw_and_rounded():
    clockwise = shapely.Polygon(
        [(500000, 5100000), (500000, 5100100), (500100, 5100100), (500100, 5100000)]
    )
    assert not clockwise.exterior.is_ccw
    geojson = to_wgs84_geojson(clockwise, CRS.from_epsg(32632))
    assert geojson["type"] == "Polygon"
    ring = np.array(geojson["coordinates"][0])
    assert shapely.LinearRing(ring).is_ccw
    assert np.all(np.abs(ring[:, 0] - 9.0) < 0.01) and np.all(np.abs(ring[:, 1] - 46.054) < 0.002)
    assert np.array_equal(ring, np.round(ring, 7))

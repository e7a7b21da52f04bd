"""OGC API – Features: the API itself on SQLite and PostgreSQL, and GDAL's OAPIF driver
(ogrinfo, a client no one here wrote) against a live server."""

import os
import re
import shutil
import subprocess

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from tests.monitoring_helpers import LiveServer, seed_detections

GEOJSON = "application/geo+json"


@pytest.fixture
def seeded(gis_app: FastAPI) -> dict[str, int]:
    return seed_detections(gis_app)


def test_landing_page_links_service_desc_and_conformance(client: TestClient, auth: dict) -> None:
    landing = client.get("/ogc", headers=auth)
    assert landing.status_code == 200
    rels = {link["rel"]: link for link in landing.json()["links"]}
    assert {"self", "service-desc", "conformance", "data"} <= set(rels)
    assert client.get(rels["service-desc"]["href"]).json()["openapi"].startswith("3.")
    conformance = client.get("/ogc/conformance", headers=auth).json()["conformsTo"]
    assert "http://www.opengis.net/spec/ogcapi-features-1/1.0/conf/core" in conformance
    assert "http://www.opengis.net/spec/ogcapi-features-1/1.0/conf/geojson" in conformance


def test_collections_have_extents_and_items_links(
    client: TestClient, auth: dict, seeded: dict
) -> None:
    collections = client.get("/ogc/collections", headers=auth).json()["collections"]
    assert [c["id"] for c in collections] == ["sites", "surveys", "detections"]
    detections = client.get("/ogc/collections/detections", headers=auth).json()
    west, south, east, north = detections["extent"]["spatial"]["bbox"][0]
    assert (west, south) == pytest.approx((9.001, 46.001))
    assert (east, north) == pytest.approx((9.0194, 46.0154))
    assert detections["extent"]["temporal"]["interval"] == [
        ["2026-07-01T10:00:00Z", "2026-08-01T10:00:00Z"]
    ]
    assert any(link["rel"] == "items" and link["type"] == GEOJSON for link in detections["links"])


def test_items_page_through_next_links_with_counts(
    client: TestClient, auth: dict, seeded: dict
) -> None:
    url, seen, pages = "/ogc/collections/detections/items?limit=12", [], 0
    while url and pages < 10:
        response = client.get(url, headers=auth)
        assert response.status_code == 200
        assert response.headers["content-type"].startswith(GEOJSON)
        page = response.json()
        assert page["numberMatched"] == 30
        assert page["numberReturned"] == len(page["features"]) <= 12
        seen += [f["id"] for f in page["features"]]
        url = next((link["href"] for link in page["links"] if link["rel"] == "next"), None)
        pages += 1
    assert pages == 3
    assert len(seen) == len(set(seen)) == 30


def test_bbox_and_datetime_filter_detections(client: TestClient, auth: dict, seeded: dict) -> None:
    def matched(**params) -> int:
        response = client.get("/ogc/collections/detections/items", params=params, headers=auth)
        assert response.status_code == 200, response.text
        return response.json()["numberMatched"]

    # The first two columns of the 5 × 5 grid (lon 9.001 and 9.003).
    assert matched(bbox="9.0,46.0,9.0035,46.02") == 10
    assert matched(datetime="2026-07-01T10:00:00Z") == 25
    assert matched(datetime="2026-07-15T00:00:00Z/..") == 5
    assert matched(datetime="../2026-07-02") == 25
    assert matched(datetime="2026-06-01T00:00:00Z/2026-12-31T00:00:00Z") == 30
    assert matched(bbox="9.0,46.0,9.0035,46.02", datetime="2026-08-01T00:00:00Z/..") == 0
    assert matched(comparison_id=seeded["august"]) == 5
    assert matched(site_id=seeded["site"] + 1) == 0
    surveys = client.get(
        "/ogc/collections/surveys/items", params={"datetime": "2026-06-15/.."}, headers=auth
    ).json()
    assert [f["properties"]["datetime"] for f in surveys["features"]] == [
        "2026-07-01T10:00:00Z",
        "2026-08-01T10:00:00Z",
    ]


def test_single_items_and_missing_ones(client: TestClient, auth: dict, seeded: dict) -> None:
    first = client.get("/ogc/collections/detections/items?limit=1", headers=auth).json()
    feature_id = first["features"][0]["id"]
    feature = client.get(f"/ogc/collections/detections/items/{feature_id}", headers=auth)
    assert feature.status_code == 200 and feature.json()["type"] == "Feature"
    assert feature.json()["properties"]["datetime"] == "2026-07-01T10:00:00Z"
    site = client.get(f"/ogc/collections/sites/items/{seeded['site']}", headers=auth).json()
    assert site["geometry"]["type"] == "Polygon" and site["properties"]["surveys"] == 3
    assert client.get("/ogc/collections/detections/items/99999", headers=auth).status_code == 404
    # Intervals as flat columns, for GIS clients; null where the detection has none.
    july = feature.json()["properties"]
    assert july["area_m2_ci95_low"] is None and july["lod_m"] is None
    august = client.get(
        "/ogc/collections/detections/items",
        params={"datetime": "2026-08-01T10:00:00Z", "limit": 1},
        headers=auth,
    ).json()["features"][0]["properties"]
    assert august["area_m2_ci95_low"] <= august["area_m2"] <= august["area_m2_ci95_high"]
    assert august["volume_loss_m3_ci95_low"] <= august["volume_loss_m3"]
    assert august["volume_loss_m3"] <= august["volume_loss_m3_ci95_high"]
    assert (august["volume_gain_m3_ci95_low"], august["volume_gain_m3_ci95_high"]) == (36, 44)
    assert august["lod_m"] == 0.12
    missing = client.get("/ogc/collections/landslides/items", headers=auth)
    assert missing.status_code == 404 and "sites, surveys, detections" in missing.json()["detail"]


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"limit": "0"}, "limit must be between 1 and 10000"),
        ({"limit": "10001"}, "limit must be between 1 and 10000"),
        ({"limit": "ten"}, "is not an integer"),
        ({"bbox": "1,2,3"}, "must be 4 numbers"),
        ({"bbox": "9,46,8,47"}, "antimeridian"),
        ({"bbox": "0,95,1,96"}, "outside"),
        ({"datetime": "yesterday"}, "not an RFC 3339 date-time"),
        ({"datetime": "2026-08-01T00:00:00Z/2026-07-01T00:00:00Z"}, "ends before it starts"),
        ({"bbox": "1,2,3,4", "bbox-crs": "EPSG:3857"}, "bbox-crs"),
    ],
)
def test_bad_parameters_get_a_400_that_says_why(
    client: TestClient, auth: dict, params: dict, message: str
) -> None:
    response = client.get("/ogc/collections/detections/items", params=params, headers=auth)
    assert response.status_code == 400
    assert message in response.json()["detail"]


def test_token_in_header_or_query_and_never_in_links(
    client: TestClient, token: str, gis_app: FastAPI
) -> None:
    assert client.get("/ogc/collections").status_code == 401
    assert client.get("/ogc", params={"api_key": "sw_wrong"}).status_code == 401
    landing = client.get("/ogc", params={"api_key": token}, headers={"Host": "evil.example"})
    assert landing.status_code == 200
    public = gis_app.state.settings.resolved_public_url
    for link in landing.json()["links"]:
        # At the configured public URL, not the Host the client sent; no token in it.
        assert link["href"].startswith(public + "/") and token not in link["href"]


def _ogrinfo(url: str, *args: str, layer: str | None = None, env: dict | None = None) -> str:
    assert shutil.which("ogrinfo"), "ogrinfo (Debian gdal-bin) is needed: make install"
    result = subprocess.run(
        ["ogrinfo", "-ro", *args, f"OAPIF:{url}", *([layer] if layer else [])],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "CPL_DEBUG": "OFF", **(env or {})},
    )
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_gdal_oapif_lists_collections_and_pages_with_filters(
    gis_app: FastAPI, seeded: dict, token: str
) -> None:
    # Links carry no token: GDAL sends the header with every request (QGIS: an "API
    # header" authentication configuration).
    header = {"GDAL_HTTP_HEADERS": f"Authorization: Bearer {token}"}
    with LiveServer(gis_app) as server:
        landing = f"{server.url}/ogc"
        listing = _ogrinfo(landing, env=header)
        assert re.findall(r"^\d+: (\w+)", listing, re.MULTILINE) == [
            "sites",
            "surveys",
            "detections",
        ]
        # PAGE_SIZE 10: the 25 July detections in the box come over three pages.
        features = _ogrinfo(
            landing,
            "-q",
            "-oo",
            "PAGE_SIZE=10",
            "-spat",
            "9.0",
            "46.0",
            "9.0105",
            "46.012",
            "-where",
            "datetime <= '2026-07-15T00:00:00Z'",
            layer="detections",
            env=header,
        )
        ids = re.findall(r"OGRFeature\(detections\):(\d+)", features)
        assert len(ids) == len(set(ids)) == 25
        assert f"comparison_id (Integer) = {seeded['july']}" in features
        assert f"comparison_id (Integer) = {seeded['august']}" not in features
        summary = _ogrinfo(f"{server.url}/ogc", "-so", layer="detections", env=header)
        assert "Feature Count: 30" in summary

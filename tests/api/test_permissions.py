"""Who may see and change what: every route declares its permission, and the roles hold.

The matrix (role × route family) as tested below:

    family                                   viewer  analyst  manager  admin  no role
    read: site, surveys, comparisons, jobs,    yes     yes      yes     yes    404
          schedules, reports, OGC, STAC
    analyse: new survey, compare, confirm      403     yes      yes     yes    404
    manage: site, alerts, webhooks,            403     403      yes     yes    404
            schedules, members, audit, delete
    make or unmake admins                      403     403      403     yes    404
"""

from collections.abc import Iterator

import pytest
from fastapi import FastAPI
from fastapi.routing import APIRoute
from fastapi.testclient import TestClient

from backend.api.access import PERMISSION_ATTRIBUTE
from backend.api.routes import __path__ as ROUTES_PATH
from backend.db.models import Organisation
from backend.services.users import create_user
from tests.api_helpers import join, run_job_inline
from tests.monitoring_helpers import finished_comparison

PASSWORD = "landslide-2026"
# Routes open to all, each for its reason.
PUBLIC = {
    ("GET", "/health"): "the load balancer's probe",
    ("POST", "/api/v1/auth/sign-in"): "how one gets a token",
    ("OPTIONS", "/api/v1/uploads"): "tus: what the server supports",
    ("GET", "/app-config.json"): "what the map needs before sign-in",
    ("GET", "/"): "the map's page",
    ("GET", "/docs"): "the API's documentation (its schema is public too)",
    ("GET", "/docs/api-docs.js"): "the documentation page's script",
    ("GET", "/redoc"): "a redirect to /docs",
}


# Routers the app includes at its root; the others are under /api/v1.
AT_ROOT = {"health", "ogc", "stac", "frontend", "api_docs"}


def _routes() -> Iterator[tuple[str, APIRoute]]:
    """Every route of every router of backend/api/routes, with its full path."""
    import importlib
    import pkgutil

    for module in pkgutil.iter_modules(ROUTES_PATH):
        router = importlib.import_module(f"backend.api.routes.{module.name}").router
        prefix = "" if module.name in AT_ROOT else "/api/v1"
        for route in router.routes:
            if isinstance(route, APIRoute):
                yield prefix + route.path_format, route


def _permissions(dependant) -> set[str]:
    found = set()
    for sub in dependant.dependencies:
        if hasattr(sub.call, PERMISSION_ATTRIBUTE):
            found.add(getattr(sub.call, PERMISSION_ATTRIBUTE))
        found |= _permissions(sub)
    return found


def test_every_route_declares_its_permission(app: FastAPI) -> None:
    """A route added without one of backend/api/access.py's dependencies fails here."""
    checked, undeclared = set(), []
    for path, route in _routes():
        checked.add(path)
        for method in route.methods:
            if not _permissions(route.dependant) and (method, path) not in PUBLIC:
                undeclared.append(f"{method} {path}")
    assert undeclared == [], f"routes with no declared permission: {undeclared}"
    # Every operation of the API is among the routes checked.
    assert set(app.openapi()["paths"]) <= checked


@pytest.fixture
def site(client: TestClient, auth: dict) -> int:
    return client.post("/api/v1/sites", json={"name": "East flank"}, headers=auth).json()["id"]


@pytest.fixture
def people(app: FastAPI, client: TestClient, site: int) -> dict[str, dict]:
    """A user of each role in the site's organisation, and one of another organisation."""
    headers = {}
    with app.state.sessionmaker() as session:
        other = Organisation(name="Other town")
        session.add(other)
        for role in ("viewer", "analyst", "manager", "admin", "outsider"):
            user = create_user(session, role, PASSWORD)
            session.flush()
            join(session, user.id, "admin" if role == "outsider" else role,
                 other if role == "outsider" else None)  # fmt: skip
        session.commit()
    for role in ("viewer", "analyst", "manager", "admin", "outsider"):
        body = {"username": role, "password": PASSWORD}
        token = client.post("/api/v1/auth/sign-in", json=body).json()["token"]
        headers[role] = {"Authorization": f"Bearer {token}"}
    return headers


def _families(site: int) -> dict[str, list[tuple[str, str, dict | None]]]:
    s = f"/api/v1/sites/{site}"
    return {
        "read": [
            ("GET", s, None),
            ("GET", f"{s}/surveys", None),
            ("GET", f"{s}/comparisons", None),
            ("GET", f"{s}/jobs", None),
            ("GET", f"{s}/schedules", None),
            ("GET", f"{s}/reports", None),
            ("GET", f"/stac/sites/{site}/collection.json", None),
        ],
        "analyse": [
            ("POST", f"{s}/surveys/sources", {"kind": "images", "name": "x",
                                             "captured_at": "2026-06-01T10:00:00Z"}),
            ("POST", f"{s}/comparisons", {}),  # 422 once allowed
            ("POST", f"{s}/reports", {"comparison_id": "x"}),
            ("PATCH", f"{s}/surveys/999", {"name": "x"}),  # 404 of the survey once allowed
            ("PATCH", f"{s}/comparisons/999", {"name": "x"}),
            ("GET", f"{s}/uploads", None),
        ],
        "manage": [
            ("PATCH", s, {"description": "watched weekly"}),
            ("GET", f"{s}/alerts", None),
            ("PUT", f"{s}/alerts", {"min_area_m2": 10}),
            ("GET", f"{s}/webhooks", None),
            ("GET", f"{s}/deliveries", None),
            ("POST", f"{s}/schedules", {"cron": "0 6 * * 1"}),
            ("DELETE", f"{s}/surveys/999", None),  # 404 of the survey once allowed
        ],
    }  # fmt: skip


ALLOWED = {
    "viewer": {"read"},
    "analyst": {"read", "analyse"},
    "manager": {"read", "analyse", "manage"},
    "admin": {"read", "analyse", "manage"},
}


@pytest.mark.parametrize("role", ["viewer", "analyst", "manager", "admin", "outsider"])
def test_the_matrix_of_roles_and_route_families(
    client: TestClient, site: int, people: dict, role: str
) -> None:
    for family, requests in _families(site).items():
        for method, path, body in requests:
            response = client.request(method, path, json=body, headers=people[role])
            code = response.status_code
            if role == "outsider":
                assert code == 404, (role, method, path, code)
                assert response.json()["detail"] == f"site {site} not found"
            elif family in ALLOWED[role]:
                assert code not in (401, 403) and not (
                    code == 404 and "site" in response.json().get("detail", "")[:5]
                ), (role, method, path, code, response.text)
            else:
                assert code == 403, (role, method, path, code)
                assert "this needs the role" in response.json()["detail"]


def test_a_site_unseen_is_in_no_list_no_collection_and_no_catalog(
    client: TestClient, auth: dict, site: int, people: dict
) -> None:
    outsider = people["outsider"]
    assert client.get("/api/v1/sites", headers=outsider).json() == []
    features = client.get("/ogc/collections/sites/items", headers=outsider).json()["features"]
    assert features == []
    assert client.get(f"/ogc/collections/sites/items/{site}", headers=outsider).status_code == 404
    catalog = client.get("/stac/catalog.json", headers=outsider).json()
    assert [link for link in catalog["links"] if link["rel"] == "child"] == []
    assert [s["id"] for s in client.get("/api/v1/sites", headers=people["viewer"]).json()] == [site]


def test_members_are_managed_by_managers_and_admins_made_by_admins(
    client: TestClient, site: int, people: dict
) -> None:
    organisation = client.get(f"/api/v1/sites/{site}", headers=people["viewer"]).json()[
        "organisation_id"
    ]
    members = f"/api/v1/organisations/{organisation}/members"
    assert client.get(members, headers=people["analyst"]).status_code == 403
    assert client.get(members, headers=people["outsider"]).status_code == 404
    listed = client.get(members, headers=people["manager"]).json()
    assert {m["username"]: m["role"] for m in listed}["analyst"] == "analyst"

    raised = client.put(f"{members}/viewer", json={"role": "analyst"}, headers=people["manager"])
    assert raised.status_code == 200 and raised.json()["role"] == "analyst"
    to_admin = client.put(f"{members}/viewer", json={"role": "admin"}, headers=people["manager"])
    assert to_admin.status_code == 403 and "only an admin" in to_admin.json()["detail"]
    assert (
        client.put(f"{members}/viewer", json={"role": "admin"}, headers=people["admin"]).status_code
        == 200
    )
    assert client.delete(f"{members}/outsider", headers=people["admin"]).status_code == 404
    # The last admin stays: someone must be able to manage the organisation.
    client.delete(f"{members}/viewer", headers=people["admin"])
    last = client.delete(f"{members}/admin", headers=people["admin"])
    assert last.status_code == 409 and "last admin" in last.json()["detail"]


def test_who_changed_what_is_in_the_audit_log(client: TestClient, site: int, people: dict) -> None:
    manager = people["manager"]
    client.patch(f"/api/v1/sites/{site}", json={"description": "x"}, headers=manager)
    client.put(f"/api/v1/sites/{site}/alerts", json={"min_area_m2": 5}, headers=manager)
    made = client.post(
        f"/api/v1/sites/{site}/schedules", json={"cron": "0 6 * * 1"}, headers=manager
    ).json()
    client.delete(f"/api/v1/sites/{site}/schedules/{made['id']}", headers=manager)
    organisation = client.get(f"/api/v1/sites/{site}", headers=manager).json()["organisation_id"]
    client.put(
        f"/api/v1/organisations/{organisation}/members/viewer",
        json={"role": "analyst"},
        headers=manager,
    )
    log = client.get(f"/api/v1/organisations/{organisation}/audit", headers=manager).json()
    assert [(e["actor"], e["action"]) for e in log][:5] == [
        ("manager", "member.set"),
        ("manager", "schedule.delete"),
        ("manager", "schedule.create"),
        ("manager", "alerts.update"),
        ("manager", "site.update"),
    ]
    assert log[0]["details"] == {"role": "analyst", "before": "viewer"}
    assert (
        client.get(
            f"/api/v1/organisations/{organisation}/audit", headers=people["analyst"]
        ).status_code
        == 403
    )


def test_tokens_held_to_a_site_and_a_role_and_a_services_token(
    client: TestClient, auth: dict, site: int, people: dict
) -> None:
    other = client.post("/api/v1/sites", json={"name": "West flank"}, headers=auth).json()["id"]
    held = client.post(
        "/api/v1/auth/tokens",
        json={"name": "qgis", "site_id": site, "role": "viewer"},
        headers=people["manager"],
    ).json()
    qgis = {"Authorization": f"Bearer {held['token']}"}
    assert client.get(f"/api/v1/sites/{site}/surveys", headers=qgis).status_code == 200
    assert client.patch(f"/api/v1/sites/{site}", json={}, headers=qgis).status_code == 403
    assert client.get(f"/api/v1/sites/{other}", headers=qgis).status_code == 404
    assert [s["id"] for s in client.get("/api/v1/sites", headers=qgis).json()] == [site]

    organisation = client.get(f"/api/v1/sites/{site}", headers=auth).json()["organisation_id"]
    service = client.post(
        "/api/v1/auth/tokens",
        json={"name": "uploader", "organisation_id": organisation, "role": "analyst"},
        headers=auth,
    )
    assert service.status_code == 201 and service.json()["role"] == "analyst"
    uploader = {"Authorization": f"Bearer {service.json()['token']}"}
    assert (
        client.post(f"/api/v1/sites/{site}/comparisons", json={}, headers=uploader).status_code
        == 422
    )
    assert client.put(f"/api/v1/sites/{site}/alerts", json={}, headers=uploader).status_code == 403
    refused = client.post(
        "/api/v1/auth/tokens",
        json={"name": "x", "organisation_id": organisation},
        headers=people["admin"],
    )
    assert refused.status_code == 422 and "platform administrator" in refused.json()["detail"]


def _tile_at(center: list[float], zoom: int) -> tuple[int, int, int]:
    """The web-mercator tile (z, x, y) holding a TileJSON's centre."""
    import math

    lon, lat = center[0], center[1]
    n = 2**zoom
    x = int((lon + 180.0) / 360.0 * n)
    y = int((1.0 - math.asinh(math.tan(math.radians(lat))) / math.pi) / 2.0 * n)
    return zoom, x, y


def test_every_object_of_a_site_is_unseen_by_a_token_without_a_role_on_it(
    app: FastAPI, client: TestClient, auth: dict, people: dict, dsm_pair_files
) -> None:
    """Every GET route of the API at a real site's real objects (surveys, a finished
    comparison, its detections, products, tiles, jobs, a schedule, a report, OGC and STAC
    items): 404 for a token of another organisation, never 403 (which would tell that the
    object exists) nor the object; the site's manager opens each one."""
    ids = finished_comparison(client, auth, dsm_pair_files, name="North gully")
    site, comparison = ids["site"], ids["comparison"]
    s = f"/api/v1/sites/{site}"
    schedule = client.post(f"{s}/schedules", json={"cron": "0 6 * * 1"}, headers=auth).json()
    report = client.post(f"{s}/reports", json={}, headers=auth).json()
    run_job_inline(report["job_id"], "build")
    product = client.get(f"{s}/comparisons/{comparison}/products", headers=auth).json()[0]
    detection = client.get(f"{s}/comparisons/{comparison}/detections", headers=auth).json()
    feature_id = detection["features"][0]["id"]
    tilejson = client.get(f"{s}/comparisons/{comparison}/tiles/dh/tilejson.json", headers=auth)
    z, x, y = _tile_at(tilejson.json()["center"], tilejson.json()["maxzoom"])
    real = {
        "site_id": site,
        "survey_id": ids["pre"],
        "comparison_id": comparison,
        "job_id": ids["job"],
        "product_id": product["id"],
        "schedule_id": schedule["id"],
        "report_id": report["id"],
        "detection_id": feature_id,
        "layer": "dh",
        "z": z,
        "x": x,
        "y": y,
        "file_format": "gpkg",
    }
    paths = [
        path.format(**real)
        for path, operations in app.openapi()["paths"].items()
        if "get" in operations and path.startswith("/api/v1/sites/{site_id}")
    ]
    # A survey's layer is its DSM; the job's event stream is a stream (checked for the
    # outsider only); OGC and STAC items of the site's objects.
    survey_tiles = f"surveys/{ids['pre']}/tiles/"
    paths = [p.replace(f"{survey_tiles}dh", f"{survey_tiles}dsm") for p in paths]
    paths += [
        f"/ogc/collections/sites/items/{site}",
        f"/ogc/collections/surveys/items/{ids['pre']}",
        f"/ogc/collections/detections/items/{feature_id}",
        f"/stac/sites/{site}/collection.json",
        f"/stac/sites/{site}/surveys/{ids['pre']}/item.json",
        f"/stac/sites/{site}/comparisons/{comparison}/item.json",
    ]  # fmt: skip
    # The query each of those needs to answer at all (the TileJSON's centre for a point).
    lon, lat = tilejson.json()["center"][:2]
    queries = {"/schedules/preview": "?cron=0+6+*+*+1", "/heights": f"?lon={lon}&lat={lat}"}
    paths = [p + next((q for end, q in queries.items() if p.endswith(end)), "") for p in paths]
    assert len(paths) >= 46
    for path in paths:
        seen = client.get(path, headers=people["outsider"])
        assert seen.status_code == 404, (path, seen.status_code, seen.text[:200])
        if path.endswith("/events"):
            continue
        opened = client.get(path, headers=people["manager"])
        assert opened.status_code == 200, (path, opened.status_code, opened.text[:200])

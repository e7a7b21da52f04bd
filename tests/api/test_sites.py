"""Sites: create, list, read, update, delete."""

from fastapi.testclient import TestClient

AOI = {
    "type": "Polygon",
    "coordinates": [[[138.70, 35.30], [138.72, 35.30], [138.72, 35.32], [138.70, 35.30]]],
}


def test_site_lifecycle(client: TestClient, auth: dict) -> None:
    created = client.post(
        "/api/v1/sites", json={"name": "Kōchi slope 3", "area_of_interest": AOI}, headers=auth
    )
    assert created.status_code == 201
    site = created.json()
    assert site["name"] == "Kōchi slope 3"
    assert site["area_of_interest"] == AOI

    assert [s["id"] for s in client.get("/api/v1/sites", headers=auth).json()] == [site["id"]]
    assert client.get(f"/api/v1/sites/{site['id']}", headers=auth).json()["name"] == "Kōchi slope 3"

    patched = client.patch(
        f"/api/v1/sites/{site['id']}", json={"description": "east flank"}, headers=auth
    )
    assert patched.status_code == 200
    assert patched.json()["description"] == "east flank"
    assert patched.json()["name"] == "Kōchi slope 3"

    assert client.delete(f"/api/v1/sites/{site['id']}", headers=auth).status_code == 204
    missing = client.get(f"/api/v1/sites/{site['id']}", headers=auth)
    assert missing.status_code == 404
    assert missing.json()["detail"] == f"site {site['id']} not found"


def test_duplicate_name_is_a_conflict(client: TestClient, auth: dict) -> None:
    assert client.post("/api/v1/sites", json={"name": "A"}, headers=auth).status_code == 201
    response = client.post("/api/v1/sites", json={"name": "A"}, headers=auth)
    assert response.status_code == 409
    assert "exists" in response.json()["detail"]


def test_empty_name_is_rejected(client: TestClient, auth: dict) -> None:
    response = client.post("/api/v1/sites", json={"name": ""}, headers=auth)
    assert response.status_code == 422


def test_openapi_document_is_served(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    assert "/api/v1/sites/{site_id}/comparisons/{comparison_id}/detections" in spec["paths"]
    assert client.get("/docs").status_code == 200

"""Resumable uploads (tus 1.0.0): chunks, resume after a cut, checksums, plain-words refusals
before and after the bytes, termination and expiry; nothing partial is ever left behind."""

import base64
import hashlib
from collections.abc import AsyncIterator
from datetime import UTC, datetime, timedelta
from pathlib import Path

import anyio
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import func, select, update
from starlette.requests import ClientDisconnect

from backend.db.models import StoredFile, Survey, SurveyFile, Upload
from backend.services.uploads import append, current_offset
from worker.simulator.dsm_pair import DsmPairPaths

TUS = {"Tus-Resumable": "1.0.0"}


def metadata(**values: str) -> str:
    return ",".join(f"{k} {base64.b64encode(v.encode()).decode()}" for k, v in values.items())


def dsm_metadata(site_id: int, path: Path, data: bytes, **extra: str) -> str:
    return metadata(
        site_id=str(site_id),
        filename=path.name,
        purpose="dsm",
        captured_at="2026-06-01T10:00:00Z",
        name="June flight",
        sha256=hashlib.sha256(data).hexdigest(),
        **extra,
    )


def create(client: TestClient, auth: dict, length: int, meta: str):
    return client.post(
        "/api/v1/uploads",
        headers={**auth, **TUS, "Upload-Length": str(length), "Upload-Metadata": meta},
    )


def patch(client: TestClient, auth: dict, location: str, offset: int, body: bytes, **headers):
    return client.patch(
        location,
        content=body,
        headers={
            **auth,
            **TUS,
            "Upload-Offset": str(offset),
            "Content-Type": "application/offset+octet-stream",
            **headers,
        },
    )


def head_offset(client: TestClient, auth: dict, location: str) -> int:
    response = client.head(location, headers={**auth, **TUS})
    assert response.status_code == 200
    assert response.headers["Cache-Control"] == "no-store"
    return int(response.headers["Upload-Offset"])


def counts(app: FastAPI) -> tuple[int, int, int]:
    """(surveys, stored files, files on disk under storage)."""
    with app.state.sessionmaker() as session:
        surveys = session.scalar(select(func.count()).select_from(Survey))
        stored = session.scalar(select(func.count()).select_from(StoredFile))
    root = app.state.settings.storage_dir
    files = sum(1 for p in root.rglob("*") if p.is_file()) if root.exists() else 0
    return surveys, stored, files


@pytest.fixture
def site_id(client: TestClient, auth: dict) -> int:
    return client.post("/api/v1/sites", json={"name": "East flank"}, headers=auth).json()["id"]


def test_options_say_what_is_supported(client: TestClient) -> None:
    response = client.options("/api/v1/uploads")
    assert response.status_code == 204
    assert response.headers["Tus-Version"] == "1.0.0"
    assert set(response.headers["Tus-Extension"].split(",")) >= {
        "creation",
        "termination",
        "checksum",
    }
    assert response.headers["Tus-Checksum-Algorithm"] == "sha256"
    assert int(response.headers["Tus-Max-Size"]) > 0


def test_a_dsm_in_chunks_becomes_a_survey(
    client: TestClient, auth: dict, app: FastAPI, site_id: int, dsm_pair_files: DsmPairPaths
) -> None:
    data = dsm_pair_files.pre.read_bytes()
    created = create(client, auth, len(data), dsm_metadata(site_id, dsm_pair_files.pre, data))
    assert created.status_code == 201, created.text
    location = created.headers["Location"]
    assert location.startswith("/api/v1/uploads/") and "Upload-Expires" in created.headers
    chunk = len(data) // 3 + 1
    offset = 0
    while offset < len(data):
        assert head_offset(client, auth, location) == offset
        body = data[offset : offset + chunk]
        digest = base64.b64encode(hashlib.sha256(body).digest()).decode()
        response = patch(
            client, auth, location, offset, body, **{"Upload-Checksum": f"sha256 {digest}"}
        )
        assert response.status_code == 204, response.text
        offset = int(response.headers["Upload-Offset"])
    status = client.get(location, headers=auth).json()
    assert status["state"] == "complete" and status["offset"] == len(data)
    survey = client.get(
        f"/api/v1/sites/{site_id}/surveys/{status['survey_id']}", headers=auth
    ).json()
    assert survey["name"] == "June flight" and survey["status"] == "ready"
    assert survey["source_file"]["sha256"] == hashlib.sha256(data).hexdigest()
    assert survey["captured_at"].startswith("2026-06-01T10:00:00")
    assert not list((app.state.settings.storage_dir / "uploads").rglob("*.part"))


def test_a_cut_connection_resumes_where_the_bytes_stopped(
    client: TestClient, auth: dict, app: FastAPI, site_id: int, dsm_pair_files: DsmPairPaths
) -> None:
    data = dsm_pair_files.post.read_bytes()
    location = create(
        client, auth, len(data), dsm_metadata(site_id, dsm_pair_files.post, data)
    ).headers["Location"]
    upload_id = location.rsplit("/", 1)[1]

    async def cut_after(n: int) -> AsyncIterator[bytes]:
        yield data[: n // 2]
        yield data[n // 2 : n]
        raise ClientDisconnect()

    # The server side of a PATCH whose connection broke after 1000 bytes (no checksum).
    with app.state.sessionmaker() as session:
        upload = session.get(Upload, upload_id)
        with pytest.raises(ClientDisconnect):
            anyio.run(append, session, app.state.storage, upload, 0, cut_after(1000), None)
        assert current_offset(app.state.storage, upload) == 1000
    assert head_offset(client, auth, location) == 1000
    # A client that thinks it is elsewhere is told where it really is.
    conflict = patch(client, auth, location, 0, data[:10])
    assert conflict.status_code == 409 and "1000 bytes received" in conflict.json()["detail"]
    done = patch(client, auth, location, 1000, data[1000:])
    assert done.status_code == 204, done.text
    assert client.get(location, headers=auth).json()["state"] == "complete"


def test_a_damaged_request_is_dropped_whole(
    client: TestClient, auth: dict, site_id: int, dsm_pair_files: DsmPairPaths
) -> None:
    data = dsm_pair_files.pre.read_bytes()
    location = create(
        client, auth, len(data), dsm_metadata(site_id, dsm_pair_files.pre, data)
    ).headers["Location"]
    wrong = base64.b64encode(hashlib.sha256(b"something else").digest()).decode()
    response = patch(
        client, auth, location, 0, data[:500], **{"Upload-Checksum": f"sha256 {wrong}"}
    )
    assert response.status_code == 460 and "checksum mismatch" in response.json()["detail"]
    assert head_offset(client, auth, location) == 0
    response = patch(client, auth, location, 0, data[:500], **{"Upload-Checksum": "md5 AAAA"})
    assert response.status_code == 400 and "use sha256" in response.json()["detail"]


def test_a_file_that_arrived_damaged_is_refused_and_removed(
    client: TestClient, auth: dict, app: FastAPI, site_id: int, dsm_pair_files: DsmPairPaths
) -> None:
    data = dsm_pair_files.pre.read_bytes()
    before = counts(app)
    meta = dsm_metadata(site_id, dsm_pair_files.pre, data + b"x")  # announces another hash
    location = create(client, auth, len(data), meta).headers["Location"]
    response = patch(client, auth, location, 0, data)
    assert response.status_code == 422
    assert "arrived damaged" in response.json()["detail"]
    status = client.get(location, headers=auth).json()
    assert status["state"] == "failed" and "arrived damaged" in status["error"]
    assert counts(app) == before
    assert client.head(location, headers={**auth, **TUS}).status_code == 410


def test_a_tif_that_is_not_a_geotiff_is_refused_after_upload(
    client: TestClient, auth: dict, app: FastAPI, site_id: int, tmp_path: Path
) -> None:
    fake = tmp_path / "dsm.tif"
    fake.write_bytes(b"this is a text file, not a raster\n" * 10)
    data = fake.read_bytes()
    before = counts(app)
    location = create(client, auth, len(data), dsm_metadata(site_id, fake, data)).headers[
        "Location"
    ]
    response = patch(client, auth, location, 0, data)
    assert response.status_code == 422
    assert (
        response.json()["detail"] == "the upload 'dsm.tif' is not a GeoTIFF (it is not a TIFF file)"
    )
    assert counts(app) == before


@pytest.mark.parametrize(
    ("change", "status", "message"),
    [
        ({"filename": "photo.jpg"}, 415, "photo.jpg is not a GeoTIFF"),
        ({"captured_at": "last tuesday"}, 400, "is not a date and time"),
        ({"captured_at": ""}, 400, "lacks 'captured_at'"),
        ({"site_id": "999"}, 404, "site 999 does not exist"),
        ({"filename": "../../etc/passwd.tif"}, 400, "must not contain a folder"),
        ({"purpose": "anything"}, 400, "unknown purpose"),
        ({"sha256": "abc"}, 400, "64 hexadecimal digits"),
    ],
)
def test_bad_uploads_are_refused_before_any_byte(
    client: TestClient,
    auth: dict,
    app: FastAPI,
    site_id: int,
    change: dict,
    status: int,
    message: str,
) -> None:
    values = {
        "site_id": str(site_id),
        "filename": "june.tif",
        "purpose": "dsm",
        "captured_at": "2026-06-01T10:00:00Z",
        **change,
    }
    response = create(client, auth, 1000, metadata(**{k: v for k, v in values.items() if v}))
    assert response.status_code == status
    assert message in response.json()["detail"]
    assert counts(app) == (0, 0, 0)


def test_protocol_errors_say_what_is_wrong(
    client: TestClient, auth: dict, app: FastAPI, site_id: int
) -> None:
    meta = metadata(site_id=str(site_id), filename="a.tif", captured_at="2026-06-01T10:00:00Z")
    too_big = create(client, auth, app.state.settings.max_upload_bytes + 1, meta)
    assert too_big.status_code == 413 and "more than the limit" in too_big.json()["detail"]
    no_version = client.post(
        "/api/v1/uploads", headers={**auth, "Upload-Length": "10", "Upload-Metadata": meta}
    )
    assert no_version.status_code == 412 and no_version.headers["Tus-Version"] == "1.0.0"
    location = create(client, auth, 10, meta).headers["Location"]
    too_long = patch(client, auth, location, 0, b"x" * 11)
    assert too_long.status_code == 413 and "more bytes than the 10" in too_long.json()["detail"]
    wrong_type = client.patch(location, content=b"x", headers={**auth, **TUS, "Upload-Offset": "0"})
    assert wrong_type.status_code == 415
    assert client.head("/api/v1/uploads/doesnotexist", headers={**auth, **TUS}).status_code == 404


def test_termination_removes_the_bytes(
    client: TestClient, auth: dict, app: FastAPI, site_id: int
) -> None:
    meta = metadata(site_id=str(site_id), filename="a.tif", captured_at="2026-06-01T10:00:00Z")
    location = create(client, auth, 100, meta).headers["Location"]
    assert patch(client, auth, location, 0, b"II*\x00" + b"\x00" * 46).status_code == 204
    assert counts(app)[2] == 1
    assert client.delete(location, headers={**auth, **TUS}).status_code == 204
    assert counts(app) == (0, 0, 0)
    assert client.get(location, headers=auth).status_code == 404


def test_expired_uploads_are_removed(
    client: TestClient, auth: dict, app: FastAPI, site_id: int
) -> None:
    meta = metadata(site_id=str(site_id), filename="a.tif", captured_at="2026-06-01T10:00:00Z")
    old = create(client, auth, 100, meta).headers["Location"]
    patch(client, auth, old, 0, b"x" * 50)
    with app.state.sessionmaker() as session:
        session.execute(update(Upload).values(expires_at=datetime.now(UTC) - timedelta(hours=1)))
        session.commit()
    create(client, auth, 100, meta)  # each creation sweeps the expired ones
    assert client.get(old, headers=auth).status_code == 404
    assert counts(app)[2] == 1  # the new, empty upload only


def test_a_site_deleted_takes_its_unfinished_uploads(
    client: TestClient, auth: dict, app: FastAPI, site_id: int
) -> None:
    meta = metadata(site_id=str(site_id), filename="a.tif", captured_at="2026-06-01T10:00:00Z")
    location = create(client, auth, 100, meta).headers["Location"]
    patch(client, auth, location, 0, b"x" * 50)
    assert client.delete(f"/api/v1/sites/{site_id}", headers=auth).status_code == 204
    assert client.get(location, headers=auth).status_code == 404
    assert counts(app) == (0, 0, 0)


def test_a_flight_log_joins_its_video_survey(
    client: TestClient, auth: dict, app: FastAPI, site_id: int, simulated_mounds_survey
) -> None:
    flight, _truth = simulated_mounds_survey
    log = next(p for p in sorted(flight.iterdir()) if p.suffix.lower() == ".srt")
    survey = client.post(
        f"/api/v1/sites/{site_id}/surveys/sources",
        json={"kind": "video", "name": "July", "captured_at": "2026-07-01T09:00:00Z"},
        headers=auth,
    ).json()
    data = log.read_bytes()
    meta = metadata(
        site_id=str(site_id),
        filename=log.name,
        purpose="survey_file",
        survey_id=str(survey["id"]),
        role="log",
        sha256=hashlib.sha256(data).hexdigest(),
    )
    wrong_role = create(
        client,
        auth,
        len(data),
        meta.replace(base64.b64encode(b"log").decode(), base64.b64encode(b"image").decode()),
    )
    assert wrong_role.status_code == 415 and "must end with" in wrong_role.json()["detail"]
    location = create(client, auth, len(data), meta).headers["Location"]
    assert patch(client, auth, location, 0, data).status_code == 204
    status = client.get(location, headers=auth).json()
    assert status["survey_id"] == survey["id"]
    with app.state.sessionmaker() as session:
        files = session.scalars(select(SurveyFile)).all()
        assert [(f.role, f.name) for f in files] == [("log", log.name)]
        # The upload's answer says what reading the log had to assume, as the file does.
        assert status["warnings"] and status["warnings"] == files[0].warnings

"""A survey uploaded as video + SRT is reconstructed by a real worker on Redis + PostgreSQL.

Each of the five stages runs as its own Celery task on the real broker, and the survey
ends `ready` with a DSM product whose pixels match the simulator's truth in shape.
"""

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import rasterio
from fastapi.testclient import TestClient

from backend.config import Settings
from tests.api.test_uploads import patch
from tests.api_helpers import create_video_upload
from tests.integration.conftest import SlidewatchProcess, api_client, wait_for_job
from tests.video_helpers import faststart_copy
from worker.pipeline.ingest.video import VideoReader

pytestmark = pytest.mark.integration


def test_video_survey_is_reconstructed_by_a_worker(
    redis_postgres_settings: Settings,
    start_worker: Callable[..., SlidewatchProcess],
    simulated_mounds_survey,
    tmp_path: Path,
) -> None:
    flight, _ = simulated_mounds_survey
    client, auth = api_client(redis_postgres_settings)
    start_worker(redis_postgres_settings)
    site = client.post("/api/v1/sites", json={"name": "mounds"}, headers=auth).json()["id"]
    survey = client.post(
        f"/api/v1/sites/{site}/surveys/sources",
        json={"kind": "video", "name": "step 1", "captured_at": "2026-07-01T09:00:00Z"},
        headers=auth,
    ).json()
    for name, role in (("DJI_0001.MP4", "video"), ("flight-airdata.csv", "log")):
        response = client.put(
            f"/api/v1/sites/{site}/surveys/{survey['id']}/files/{name}",
            params={"role": role},
            content=(flight / name).read_bytes(),
            headers=auth,
        )
        assert response.status_code == 201, response.text
    job = client.post(f"/api/v1/sites/{site}/surveys/{survey['id']}/process", headers=auth)
    assert job.status_code == 202, job.text
    done = wait_for_job(
        client, auth, site, job.json()["id"], lambda j: j["state"] in ("succeeded", "failed")
    )
    assert done["state"] == "succeeded", done
    assert all(s["attempts"] == 1 and s["progress"] == 1.0 for s in done["stages"])
    ready = client.get(f"/api/v1/sites/{site}/surveys/{survey['id']}", headers=auth).json()
    assert ready["status"] == "ready" and ready["footprint"]["type"] == "Polygon"
    products = client.get(
        f"/api/v1/sites/{site}/surveys/{survey['id']}/products", headers=auth
    ).json()
    dsm = next(p for p in products if p["kind"] == "dsm")
    download = tmp_path / "dsm.tif"
    download.write_bytes(client.get(dsm["download_url"], headers=auth).content)
    with rasterio.open(download) as src:
        heights = src.read(1, masked=True)
    # The mound field: flat sand with mounds of about 1.5 m.
    assert heights.count() > 0.8 * heights.size
    relief = np.percentile(heights.compressed(), 99.5) - np.percentile(heights.compressed(), 1)
    assert 1.0 < relief < 2.2


def _video_arriving(
    client: TestClient, auth: dict, log: Path, tmp_path: Path
) -> tuple[int, int, bytes, str]:
    """A site, a video survey with its log, and the resumable upload of its video (index
    first, as the map sends it) with no byte sent: (site, survey, video bytes, upload URL)."""
    site = client.post("/api/v1/sites", json={"name": "mounds"}, headers=auth).json()["id"]
    sid = client.post(
        f"/api/v1/sites/{site}/surveys/sources",
        json={"kind": "video", "name": "step 1", "captured_at": "2026-07-01T09:00:00Z"},
        headers=auth,
    ).json()["id"]
    response = client.put(
        f"/api/v1/sites/{site}/surveys/{sid}/files/{log.name}",
        params={"role": "log"},
        content=log.read_bytes(),
        headers=auth,
    )
    assert response.status_code == 201, response.text
    data = faststart_copy(log.parent / "DJI_0001.MP4", tmp_path / "DJI_0001.MP4").read_bytes()
    return site, sid, data, create_video_upload(client, auth, site, sid, data)


def test_video_is_processed_while_it_uploads_and_a_stalled_upload_resumes(
    redis_postgres_settings: Settings,
    start_worker: Callable[..., SlidewatchProcess],
    simulated_mounds_survey,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The job starts on the first bytes of the video: ingest reads its header and frames
    decodes as the rest comes. The upload stalls: the job fails saying so; the upload is
    resumed, the job retried, and it ends with the survey's DSM."""
    flight, _ = simulated_mounds_survey
    monkeypatch.setenv("SLIDEWATCH_UPLOAD_STALL_TIMEOUT_S", "4")
    client, auth = api_client(redis_postgres_settings)
    start_worker(redis_postgres_settings)
    site, sid, data, location = _video_arriving(
        client, auth, flight / "flight-airdata.csv", tmp_path
    )
    half = len(data) // 2
    assert patch(client, auth, location, 0, data[:half]).status_code == 204
    job_id = client.post(f"/api/v1/sites/{site}/surveys/{sid}/process", headers=auth).json()["id"]

    def stage(job: dict, name: str) -> dict:
        return next(s for s in job["stages"] if s["stage"] == name)

    # Half the video is there: ingest is done and frames is decoding what arrived.
    running = wait_for_job(
        client, auth, site, job_id, lambda j: stage(j, "frames")["state"] == "running"
    )
    assert stage(running, "ingest")["state"] == "succeeded"
    assert client.get(location, headers=auth).json()["offset"] == half
    # No more bytes: after the stall timeout the job fails, saying where the upload stopped.
    failed = wait_for_job(client, auth, site, job_id, lambda j: j["state"] == "failed")
    assert f"DJI_0001.MP4: the upload stopped at {half} of {len(data)} bytes" in failed["error"]
    # The user resumes the upload (it joins the failed survey), then retries the job.
    assert patch(client, auth, location, half, data[half:]).status_code == 204
    assert client.get(location, headers=auth).json()["state"] == "complete"
    retried = client.post(f"/api/v1/sites/{site}/jobs/{job_id}/retry", headers=auth)
    assert retried.status_code == 202, retried.text
    done = wait_for_job(client, auth, site, job_id, lambda j: j["state"] in ("succeeded", "failed"))
    assert done["state"] == "succeeded", done
    assert [s["attempts"] for s in done["stages"]] == [1, 2, 1, 1, 1, 1]
    survey = client.get(f"/api/v1/sites/{site}/surveys/{sid}", headers=auth).json()
    assert survey["status"] == "ready"
    files = client.get(f"/api/v1/sites/{site}/surveys/{sid}/files", headers=auth).json()
    assert sorted(f["role"] for f in files) == ["log", "video"]


def test_a_video_arriving_in_pieces_is_reconstructed_as_it_comes(
    redis_postgres_settings: Settings,
    start_worker: Callable[..., SlidewatchProcess],
    simulated_mounds_survey,
    tmp_path: Path,
) -> None:
    """Pieces of the video arrive a second apart: the frames stage is under way before
    the last one, and the job goes through with every stage once."""
    flight, _ = simulated_mounds_survey
    client, auth = api_client(redis_postgres_settings)
    start_worker(redis_postgres_settings)
    site, sid, data, location = _video_arriving(client, auth, flight / "DJI_0001.SRT", tmp_path)
    pieces = 6
    step = -(-len(data) // pieces)
    assert patch(client, auth, location, 0, data[:step]).status_code == 204
    job_id = client.post(f"/api/v1/sites/{site}/surveys/{sid}/process", headers=auth).json()["id"]
    frames_running_before_last_piece = False
    for offset in range(step, len(data), step):
        time.sleep(1.0)
        job = client.get(f"/api/v1/sites/{site}/jobs/{job_id}", headers=auth).json()
        frames = next(s for s in job["stages"] if s["stage"] == "frames")
        frames_running_before_last_piece |= frames["state"] == "running"
        piece = data[offset : offset + step]
        assert patch(client, auth, location, offset, piece).status_code == 204
    assert frames_running_before_last_piece
    done = wait_for_job(client, auth, site, job_id, lambda j: j["state"] in ("succeeded", "failed"))
    assert done["state"] == "succeeded", done
    assert all(s["attempts"] == 1 and s["progress"] == 1.0 for s in done["stages"])
    frames = next(s for s in done["stages"] if s["stage"] == "frames")["result"]
    every_frame = VideoReader(tmp_path / "DJI_0001.MP4").frames(size=(64, 36))
    assert frames["frames"]["frames"] == sum(1 for _ in every_frame)  # nothing lost

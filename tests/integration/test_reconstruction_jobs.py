"""A survey uploaded as video + SRT is reconstructed by a real worker on Redis + PostgreSQL.

Each of the five stages runs as its own Celery task on the real broker, and the survey
ends `ready` with a DSM product whose pixels match the simulator's truth in shape.
"""

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import rasterio

from backend.config import Settings
from tests.integration.conftest import SlidewatchProcess, api_client, wait_for_job

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

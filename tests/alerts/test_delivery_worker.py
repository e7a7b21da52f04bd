"""A real worker delivers the alert of a finished comparison, retrying with backoff."""

import json
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from backend.config import Settings
from tests.integration.conftest import SlidewatchProcess
from tests.monitoring_helpers import (
    WebhookReceiver,
    app_for,
    token_for,
    wait_until,
)
from worker.simulator.dsm_pair import DsmPairPaths

pytestmark = pytest.mark.integration


def test_worker_retries_a_failing_webhook_with_backoff(
    tmp_path: Path, alert_pair: DsmPairPaths, monkeypatch: pytest.MonkeyPatch
) -> None:
    settings = Settings(
        data_dir=tmp_path / "data",
        delivery_retry_base_s=0.5,
        webhook_allowed_networks=["127.0.0.1/32"],  # the local receiver
    )
    with (
        WebhookReceiver(statuses=[500, 502]) as receiver,
        app_for(settings, monkeypatch) as app,
        TestClient(app) as client,
    ):
        auth = {"Authorization": f"Bearer {token_for(app)}"}
        worker = SlidewatchProcess(settings, tmp_path / "worker.log", ["worker"], b" ready.")
        worker.start()
        try:
            site = client.post("/api/v1/sites", json={"name": "slope"}, headers=auth).json()["id"]
            hook = client.post(
                f"/api/v1/sites/{site}/webhooks", json={"url": receiver.url}, headers=auth
            )
            assert hook.status_code == 201
            # The comparison runs here, or in the worker where it claimed the job first; its
            # alert is queued on commit and the worker sends it.
            ids = finished_comparison_in_site(client, auth, alert_pair, site)

            def delivered() -> dict | None:
                deliveries = client.get(f"/api/v1/sites/{site}/deliveries", headers=auth).json()
                assert len(deliveries) <= 1, deliveries
                if deliveries and deliveries[0]["status"] == "delivered":
                    return deliveries[0]
                return None

            delivery = wait_until(delivered, timeout_s=60)
        finally:
            worker.stop()
    assert [a["status_code"] for a in delivery["attempt_log"]] == [500, 502, 200], worker.log()
    times = [t for _, _, t in receiver.requests]
    assert times[1] - times[0] >= 0.45 and times[2] - times[1] >= 0.95  # 0.5 s, then 1 s
    assert json.loads(receiver.requests[-1][1])["comparison"]["id"] == ids["comparison"]


def finished_comparison_in_site(client: TestClient, auth: dict, pair: DsmPairPaths, site: int):
    from tests.api_helpers import run_job_inline, upload_dsm

    pre = upload_dsm(client, auth, site, pair.pre, "2026-06-01T10:00:00Z")
    post = upload_dsm(client, auth, site, pair.post, "2026-07-01T10:00:00Z")
    created = client.post(
        f"/api/v1/sites/{site}/comparisons",
        json={"pre_survey_id": pre["id"], "post_survey_id": post["id"], "method": "threshold"},
        headers=auth,
    ).json()
    run_job_inline(created["job"]["id"])
    return {"comparison": created["comparison"]["id"]}

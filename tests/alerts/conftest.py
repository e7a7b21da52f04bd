"""Alerts run on the embedded default; deliveries go to local HTTP and SMTP servers."""

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from backend.config import Settings
from tests.monitoring_helpers import MailReceiver, app_for, token_for
from worker.simulator.dsm_pair import DsmPairPaths, make_dsm_pair, write_dsm_pair


@pytest.fixture
def mailbox() -> Iterator[MailReceiver]:
    with MailReceiver() as receiver:
        yield receiver


@pytest.fixture
def alert_settings(tmp_path: Path, mailbox: MailReceiver) -> Settings:
    return Settings(
        data_dir=tmp_path / "data",
        smtp_host="127.0.0.1",
        smtp_port=mailbox.port,
        smtp_from="alerts@slidewatch.test",
        delivery_max_attempts=3,
        delivery_retry_base_s=0.3,
        webhook_timeout_s=5.0,
        public_url="https://slidewatch.example",
        # The local webhook receivers of these tests listen on loopback, which webhooks
        # may call only when an administrator allows it.
        webhook_allowed_networks=["127.0.0.1/32"],
    )


@pytest.fixture
def alert_app(alert_settings: Settings, monkeypatch: pytest.MonkeyPatch) -> Iterator[FastAPI]:
    with app_for(alert_settings, monkeypatch) as app:
        yield app


@pytest.fixture
def client(alert_app: FastAPI) -> Iterator[TestClient]:
    with TestClient(alert_app) as test_client:
        yield test_client


@pytest.fixture
def auth(alert_app: FastAPI) -> dict[str, str]:
    return {"Authorization": f"Bearer {token_for(alert_app)}"}


@pytest.fixture(scope="session")
def alert_pair(tmp_path_factory: pytest.TempPathFactory) -> DsmPairPaths:
    pair = make_dsm_pair(shape=(240, 240), pixel_size_m=1.0, shift_m=(1.3, -0.7, 0.2), seed=7)
    return write_dsm_pair(pair, tmp_path_factory.mktemp("alert-pair"))

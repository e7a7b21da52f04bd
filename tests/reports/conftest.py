"""Reports: built in this process on the embedded default, and through real beat + worker."""

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
def report_app(
    tmp_path: Path, mailbox: MailReceiver, monkeypatch: pytest.MonkeyPatch
) -> Iterator[FastAPI]:
    settings = Settings(
        data_dir=tmp_path / "data",
        smtp_host="127.0.0.1",
        smtp_port=mailbox.port,
        webhook_allowed_networks=["127.0.0.1/32"],  # the local webhook receiver
    )
    with app_for(settings, monkeypatch) as app:
        yield app


@pytest.fixture
def client(report_app: FastAPI) -> Iterator[TestClient]:
    with TestClient(report_app) as test_client:
        yield test_client


@pytest.fixture
def auth(report_app: FastAPI) -> dict[str, str]:
    return {"Authorization": f"Bearer {token_for(report_app)}"}


@pytest.fixture(scope="session")
def report_pair(tmp_path_factory: pytest.TempPathFactory) -> DsmPairPaths:
    pair = make_dsm_pair(shape=(240, 240), pixel_size_m=1.0, shift_m=(1.3, -0.7, 0.2), seed=7)
    return write_dsm_pair(pair, tmp_path_factory.mktemp("report-pair"))

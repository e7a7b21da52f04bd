"""Every delivery error is a recorded attempt, and attempts end at the limit.

Whatever goes wrong while sending (here a recipient stored as a number, which the e-mail
library cannot even take for an address) is logged as that attempt's error; a delivery
whose attempts are used up (one that died with its worker counted too) fails instead of
being tried again every time the sweep finds it overdue.
"""

from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import update

from backend.db.models import Delivery, DeliveryStatus, Site
from backend.services.alerts import attempt_delivery, create_deliveries
from tests.monitoring_helpers import MailReceiver


def _email_delivery(app: FastAPI, client: TestClient, auth: dict) -> int:
    site_id = client.post("/api/v1/sites", json={"name": "watched"}, headers=auth).json()["id"]
    put = client.put(
        f"/api/v1/sites/{site_id}/alerts", json={"email_recipients": ["a@b.example"]}, headers=auth
    )
    assert put.status_code == 200, put.text
    with app.state.sessionmaker() as session:
        site = session.get(Site, site_id)
        payload = {"event": "job_failed", "site": {"id": site.id, "name": site.name}}
        created = create_deliveries(
            session, app.state.settings, site, "job_failed", "job:1", payload, "failed"
        )
        session.commit()
        return next(d.id for d in created if d.channel == "email")


def _attempt(app: FastAPI, delivery_id: int):
    return attempt_delivery(
        delivery_id, app.state.sessionmaker, app.state.storage, app.state.settings
    )


def _stored(app: FastAPI, delivery_id: int) -> Delivery:
    with app.state.sessionmaker() as session:
        delivery = session.get(Delivery, delivery_id)
        list(delivery.attempt_log)  # loaded while the session is open
        session.expunge_all()
        return delivery


def test_an_unexpected_sending_error_is_a_recorded_attempt(
    alert_app: FastAPI, client: TestClient, auth: dict, mailbox: MailReceiver
) -> None:
    delivery_id = _email_delivery(alert_app, client, auth)
    with alert_app.state.sessionmaker() as session:
        session.execute(update(Delivery).values(recipients=[123]))  # not even a string
        session.commit()
    outcomes = [_attempt(alert_app, delivery_id) for _ in range(3)]
    assert [o.delivered for o in outcomes] == [False] * 3 and all(o.error for o in outcomes)
    assert mailbox.messages == []
    delivery = _stored(alert_app, delivery_id)
    assert delivery.status == DeliveryStatus.failed and delivery.attempts == 3
    assert delivery.last_error.startswith("gave up after 3 attempts")
    assert len(delivery.attempt_log) == 3 and all(a.error for a in delivery.attempt_log)
    assert _attempt(alert_app, delivery_id).retry_in_s is None  # nothing more to do


def test_a_delivery_whose_attempts_are_used_up_fails_when_found_again(
    alert_app: FastAPI, client: TestClient, auth: dict, mailbox: MailReceiver
) -> None:
    delivery_id = _email_delivery(alert_app, client, auth)
    # As a worker killed in its last attempt leaves it: claimed, counted, not recorded.
    with alert_app.state.sessionmaker() as session:
        session.execute(
            update(Delivery).values(attempts=3, status=DeliveryStatus.retrying, last_error=None)
        )
        session.commit()
    outcome = _attempt(alert_app, delivery_id)
    assert not outcome.delivered and outcome.retry_in_s is None
    assert mailbox.messages == []
    delivery = _stored(alert_app, delivery_id)
    assert delivery.status == DeliveryStatus.failed and delivery.attempts == 3
    assert delivery.last_error == "gave up after 3 attempts: the last attempt did not finish"

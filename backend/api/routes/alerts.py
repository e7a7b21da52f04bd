"""Alert thresholds, webhooks and the delivery log of a site."""

import secrets
from typing import Annotated

from fastapi import APIRouter, HTTPException, Query, Response, status
from sqlalchemy import select

from backend.api.access import SignedIn, SiteManager
from backend.api.deps import SessionDep, SettingsDep, owned_by_site
from backend.api.schemas_monitoring import (
    AlertSettingsIn,
    AlertSettingsOut,
    DeliveryOut,
    WebhookCreate,
    WebhookCreated,
    WebhookOut,
    WebhookUpdate,
)
from backend.db.models import AlertSettings, Delivery, Webhook, utcnow
from backend.ids import RowId
from backend.outbound import UrlRefused, parse_networks, resolve_target
from backend.services.alerts import (
    EMAIL_UNAVAILABLE,
    EmailUnavailable,
    alert_settings,
    check_email_available,
    test_delivery,
)
from backend.services.audit import record

router = APIRouter(prefix="/sites/{site_id}", tags=["alerts"])


def _settings_out(rules: AlertSettings, settings: SettingsDep) -> AlertSettingsOut:
    available = bool(settings.smtp_host)
    return AlertSettingsOut.model_validate(rules).model_copy(
        update={
            "email_available": available,
            "email_unavailable_reason": None if available else EMAIL_UNAVAILABLE,
        }
    )


@router.get("/alerts", response_model=AlertSettingsOut, summary="When the site alerts")
def get_alert_settings(
    site: SiteManager, session: SessionDep, settings: SettingsDep
) -> AlertSettingsOut:
    return _settings_out(alert_settings(session, site.id), settings)


@router.put(
    "/alerts",
    response_model=AlertSettingsOut,
    summary="Set when the site alerts",
    responses={409: {"description": "E-mail recipients while no SMTP server is configured."}},
)
def put_alert_settings(
    body: AlertSettingsIn,
    site: SiteManager,
    session: SessionDep,
    token: SignedIn,
    server: SettingsDep,
) -> AlertSettingsOut:
    """Thresholds for `landslides_detected` (all must hold), e-mail recipients, job failures.

    E-mail recipients are refused (409) while SLIDEWATCH_SMTP_HOST is unset: nothing could
    be sent to them."""
    if body.email_recipients:
        try:
            check_email_available(server)
        except EmailUnavailable as exc:
            raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from None
    settings = session.get(AlertSettings, site.id)
    if settings is None:
        settings = AlertSettings(site_id=site.id)
        session.add(settings)
    for field, value in body.model_dump().items():
        setattr(settings, field, value)
    settings.updated_at = utcnow()
    record(session, token, "alerts.update", site=site, target=f"site {site.id}",
           details=body.model_dump())  # fmt: skip
    session.commit()
    return _settings_out(settings, server)


@router.post(
    "/alerts/test-email",
    response_model=DeliveryOut,
    status_code=status.HTTP_202_ACCEPTED,
    summary="Send a test e-mail to the site's recipients (see the delivery log)",
    responses={409: {"description": "No SMTP server is configured, or no recipient set."}},
)
def send_test_email(
    site: SiteManager, session: SessionDep, settings: SettingsDep, token: SignedIn
) -> Delivery:
    try:
        delivery = test_delivery(session, settings, site, None, token.name)
    except (EmailUnavailable, LookupError) as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from None
    record(session, token, "alerts.test_email", site=site, target=f"delivery {delivery.id}")
    session.commit()
    return delivery


@router.post(
    "/webhooks",
    response_model=WebhookCreated,
    status_code=status.HTTP_201_CREATED,
    summary="Add a webhook; its signing secret is in this response only",
)
def create_webhook(
    body: WebhookCreate,
    site: SiteManager,
    session: SessionDep,
    settings: SettingsDep,
    token: SignedIn,
) -> WebhookCreated:
    """The URL must resolve to public addresses only (or to a network of
    SLIDEWATCH_WEBHOOK_ALLOWED_NETWORKS); it is checked again at every call."""
    try:
        resolve_target(body.url, parse_networks(settings.webhook_allowed_networks))
    except UrlRefused as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc)) from None
    webhook = Webhook(
        site_id=site.id, secret="whsec_" + secrets.token_urlsafe(32), **body.model_dump()
    )
    session.add(webhook)
    session.flush()
    record(session, token, "webhook.create", site=site, target=f"webhook {webhook.id}",
           details={"url": webhook.url, "events": webhook.events})  # fmt: skip
    session.commit()
    return WebhookCreated(**WebhookOut.model_validate(webhook).model_dump(), secret=webhook.secret)


@router.get("/webhooks", response_model=list[WebhookOut])
def list_webhooks(site: SiteManager, session: SessionDep) -> list[Webhook]:
    return list(
        session.scalars(select(Webhook).where(Webhook.site_id == site.id).order_by(Webhook.id))
    )


@router.patch("/webhooks/{webhook_id}", response_model=WebhookOut)
def update_webhook(
    webhook_id: RowId, body: WebhookUpdate, site: SiteManager, session: SessionDep, token: SignedIn
) -> Webhook:
    webhook = owned_by_site(session, Webhook, site, webhook_id, "webhook")
    changes = {k: v for k, v in body.model_dump(exclude_unset=True).items() if v is not None}
    for field, value in changes.items():
        setattr(webhook, field, value)
    record(session, token, "webhook.update", site=site, target=f"webhook {webhook.id}",
           details=changes)  # fmt: skip
    session.commit()
    return webhook


@router.post(
    "/webhooks/{webhook_id}/test",
    response_model=DeliveryOut,
    status_code=status.HTTP_202_ACCEPTED,
    summary="Send the event `test` to a webhook now (see the delivery log)",
)
def test_webhook(
    webhook_id: RowId,
    site: SiteManager,
    session: SessionDep,
    settings: SettingsDep,
    token: SignedIn,
) -> Delivery:
    """Signed and sent by the worker like any alert (even to an inactive webhook: that is
    what a test is for); its attempts appear in the delivery log."""
    webhook = owned_by_site(session, Webhook, site, webhook_id, "webhook")
    delivery = test_delivery(session, settings, site, webhook, token.name)
    record(session, token, "webhook.test", site=site, target=f"webhook {webhook.id}")
    session.commit()
    return delivery


@router.delete("/webhooks/{webhook_id}", status_code=status.HTTP_204_NO_CONTENT)
def delete_webhook(
    webhook_id: RowId, site: SiteManager, session: SessionDep, token: SignedIn
) -> Response:
    """Delete the webhook with its deliveries."""
    webhook = owned_by_site(session, Webhook, site, webhook_id, "webhook")
    record(session, token, "webhook.delete", site=site, target=f"webhook {webhook.id}",
           details={"url": webhook.url})  # fmt: skip
    session.delete(webhook)
    session.commit()
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.get(
    "/deliveries",
    response_model=list[DeliveryOut],
    summary="The delivery log: every webhook call and e-mail with its attempts, newest first",
)
def list_deliveries(
    site: SiteManager,
    session: SessionDep,
    webhook_id: Annotated[int | None, Query()] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
) -> list[Delivery]:
    query = select(Delivery).where(Delivery.site_id == site.id)
    if webhook_id is not None:
        query = query.where(Delivery.webhook_id == webhook_id)
    return list(session.scalars(query.order_by(Delivery.id.desc()).limit(limit)))

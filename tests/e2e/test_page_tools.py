"""The site's tools in the page: a report made and downloaded, every product downloaded,
one label per detection in the page, the GeoJSON, the GeoPackage and the PDF; the GIS
addresses copied; a schedule built with its next five runs; a webhook's test delivery to a
local server; members given a role; and /docs rendered with the network cut off.

The site is prepared over the API (two DSMs and a comparison, run by the live worker), so
the browser time goes to the panels themselves.
"""

import os
import re
from collections.abc import Iterator
from dataclasses import dataclass

import httpx
import pyogrio
import pytest
from playwright.sync_api import Locator, Page, expect
from pypdf import PdfReader
from sqlalchemy.orm import Session

from backend.db.session import make_engine
from backend.services.users import create_user
from tests.e2e.conftest import ARTIFACTS, REPO, USER, App, compare_uploaded
from tests.e2e.test_map import sign_in
from tests.monitoring_helpers import WebhookReceiver
from worker.simulator.dsm_pair import DsmPairPaths

TIME_ZONE = "Asia/Tokyo"


@dataclass(frozen=True)
class ComparedSite:
    id: int
    comparison: int
    labels: list[int]


def docs_shot(target: Locator, name: str) -> None:
    """A panel as a test artifact, and into the docs when SLIDEWATCH_DOCS_SCREENSHOTS asks."""
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    target.screenshot(path=str(ARTIFACTS / f"{name}.png"))
    docs = os.environ.get("SLIDEWATCH_DOCS_SCREENSHOTS")
    if docs:
        (REPO / docs).mkdir(parents=True, exist_ok=True)
        target.screenshot(path=str(REPO / docs / f"{name}.png"))


@pytest.fixture(scope="module")
def compared_site(app_server: App, dsm_pair: DsmPairPaths) -> Iterator[ComparedSite]:
    with httpx.Client(base_url=f"{app_server.url}/api/v1", timeout=60) as api:
        token = api.post("/auth/sign-in", json=USER).json()["token"]
        api.headers["Authorization"] = f"Bearer {token}"
        site = api.post("/sites", json={"name": "Tools slope", "timezone": TIME_ZONE}).json()
        comparison = compare_uploaded(
            api,
            site["id"],
            [
                (dsm_pair.pre, "2026-06-01T10:00:00Z", None),
                (dsm_pair.post, "2026-07-01T10:00:00Z", None),
            ],
        )
        features = api.get(f"/sites/{site['id']}/comparisons/{comparison}/detections").json()
        labels = [f["properties"]["label"] for f in features["features"]]
        assert labels == list(range(1, len(labels) + 1)) and labels
        yield ComparedSite(site["id"], comparison, labels)


def _open_site(page: Page, app: App, site: ComparedSite) -> None:
    sign_in(page, app)
    page.goto(f"{app.url}/#/sites/{site.id}")
    expect(page.get_by_role("heading", name="Tools slope", level=1)).to_be_visible()


def test_a_report_is_made_and_every_label_agrees(
    page: Page, app_server: App, compared_site: ComparedSite, tmp_path
) -> None:
    _open_site(page, app_server, compared_site)
    # The page's list: the comparison's labels, never database ids; plurals right.
    buttons = page.locator("#detections button[data-detection]")
    expect(buttons).to_have_count(len(compared_site.labels))
    assert buttons.all_inner_texts() == [f"Detection {n}" for n in compared_site.labels]
    count = len(compared_site.labels)
    expect(page.locator("#comparisons")).to_contain_text(
        f"{count} detection{'' if count == 1 else 's'}, "
    )

    page.get_by_text("Reports", exact=True).click()
    page.get_by_role("button", name="Make a report now").click()
    pdf_button = page.locator("#report-list li").first.get_by_role("button", name="PDF")
    expect(pdf_button).to_be_visible(timeout=60_000)
    expect(page.locator("#report-list li").first).to_contain_text("GMT+9")  # en-GB for JST
    with page.expect_download() as pdf:
        pdf_button.click()
    text = "\n".join(p.extract_text() for p in PdfReader(pdf.value.path()).pages)
    assert f"Times in {TIME_ZONE}." in text and "JST" in text
    with page.expect_download() as html:
        page.locator("#report-list li").first.get_by_role("button", name="HTML").click()
    assert "Landslide monitoring report" in html.value.path().read_text(encoding="utf-8")
    docs_shot(page.locator("#reports-section"), "panel-reports")

    page.get_by_text("Downloads", exact=True).click()
    products = page.locator("[data-role=comparison-products]")
    expect(products.get_by_role("button", name=re.compile("Δh"))).to_be_visible()
    expect(
        page.locator("[data-survey-products]").first.get_by_role("button", name=re.compile("DSM"))
    ).to_be_visible()
    # Every format of the detections, each read back by GDAL with the same labels.
    for name, ending, reader in (
        ("GeoPackage", ".gpkg", ""),
        ("GeoJSON", ".geojson", ""),
        ("KML", ".kml", ""),
        ("Shapefile (zip)", ".shp.zip", "/vsizip/"),
    ):
        with page.expect_download() as detections:
            products.get_by_role("button", name=f"Detections as {name}").click()
        assert detections.value.suggested_filename.endswith(ending)
        saved = tmp_path / detections.value.suggested_filename
        detections.value.save_as(saved)
        read = pyogrio.read_dataframe(f"{reader}{saved}")
        assert [int(v) for v in read["label"]] == compared_site.labels, name
    with page.expect_download() as dsm:
        page.locator("[data-survey-products]").first.get_by_role(
            "button", name=re.compile("DSM")
        ).click()
    assert dsm.value.suggested_filename.endswith(".tif")
    docs_shot(page.locator("#downloads-section"), "panel-downloads")
    # The table of the PDF numbers them the same way: "1", its area, ... on each row.
    assert all(f"\n{n}\n" in text for n in compared_site.labels)


def test_gis_addresses_a_schedule_and_a_webhook_test(
    page: Page, app_server: App, compared_site: ComparedSite
) -> None:
    page.context.grant_permissions(["clipboard-read", "clipboard-write"], origin=app_server.url)
    _open_site(page, app_server, compared_site)
    page.get_by_text("Use in GIS", exact=True).click()
    wmts = page.locator("#gis-wmts")
    expect(wmts).to_have_value(
        re.compile(rf"/api/v1/sites/{compared_site.id}/wmts/WMTSCapabilities.xml$")
    )
    page.get_by_role("button", name=re.compile("^Copy WMTS")).click()
    expect(page.locator("#gis-status")).to_contain_text("Copied")
    copied = page.evaluate("navigator.clipboard.readText()")
    assert copied == wmts.input_value() and "api_key" not in copied
    token = page.evaluate("localStorage.getItem('slidewatch.token')")
    assert token not in page.locator("#gis").inner_text()
    expect(page.locator("#gis input[id^=gis-xyz]").first).to_have_value(
        re.compile(r"\{z\}/\{x\}/\{y\}\.png$")
    )
    docs_shot(page.locator("#gis-section"), "panel-gis")

    page.get_by_text("Monitoring schedules", exact=True).click()
    page.get_by_label("Make a report").select_option("weekly")
    page.locator("#schedule-weekday").select_option(label="Monday")
    page.locator("#schedule-hour").select_option("6")
    expect(page.get_by_label(re.compile("^Cron expression"))).to_have_value("0 6 * * 1")
    runs = page.locator("#schedule-next li")
    expect(runs).to_have_count(5)
    expect(runs.first).to_contain_text("06:00 GMT+9")
    page.get_by_label(re.compile("^Cron expression")).fill("0 25 * * *")
    expect(page.locator("#schedule-error")).to_contain_text("five fields")
    page.get_by_label(re.compile("^Cron expression")).fill("30 7 * * *")
    expect(runs.first).to_contain_text("07:30")
    page.get_by_role("button", name="Save schedule").click()
    expect(page.locator("#schedule-list")).to_contain_text("30 7 * * *")
    docs_shot(page.locator("#schedules-section"), "panel-schedules")

    page.get_by_text("Alerts", exact=True).click()
    # No SMTP server here: e-mail is off, and the page says why.
    expect(page.locator("#alert-email-reason")).to_contain_text("SLIDEWATCH_SMTP_HOST is unset")
    expect(page.get_by_role("button", name="Send a test e-mail")).to_be_disabled()
    with WebhookReceiver() as receiver:
        page.get_by_label(re.compile("^Add a webhook")).fill(receiver.url)
        page.get_by_role("button", name="Add webhook").click()
        expect(page.locator("#webhook-secret")).to_contain_text("whsec_")
        page.locator("#webhook-list li", has_text=receiver.url).get_by_role(
            "button", name="Send a test"
        ).click()
        row = page.locator("#delivery-rows tr").first
        expect(row).to_contain_text("test")
        expect(row).to_have_attribute("data-status", "delivered", timeout=30_000)
        expect(row).to_contain_text("1 attempt")
        [(headers, body, _)] = receiver.requests
        assert headers["X-Slidewatch-Event"] == "test" and b'"event":"test"' in body
    docs_shot(page.locator("#alerts-section"), "panel-alerts")


def test_members_are_given_a_role_and_removed(page: Page, app_server: App) -> None:
    engine = make_engine(app_server.settings.resolved_database_url)
    with engine.begin() as connection, Session(bind=connection) as session:
        create_user(session, "aiko", "kansoku-2026")
        session.flush()
    engine.dispose()
    sign_in(page, app_server)
    page.get_by_role("link", name="Account").click()
    form = page.locator("form[data-add-member]").first
    form.get_by_placeholder("user name").fill("aiko")
    form.get_by_label("Role", exact=True).select_option("analyst")
    form.get_by_role("button", name="Add member").click()
    row = page.locator("table.members tr", has_text="aiko")
    expect(row).to_contain_text("analyst")
    docs_shot(page.locator("#people"), "panel-members")
    page.once("dialog", lambda dialog: dialog.accept())
    row.get_by_role("button", name=re.compile("^Remove aiko")).click()
    expect(page.locator("table.members tr", has_text="aiko")).to_have_count(0)


def test_the_api_docs_render_with_no_network(page: Page, app_server: App) -> None:
    outside: list[str] = []

    def only_the_app(route) -> None:
        if route.request.url.startswith(app_server.url):
            route.continue_()
        else:
            outside.append(route.request.url)
            route.abort()

    page.route("**/*", only_the_app)
    page.goto(f"{app_server.url}/docs")
    expect(page.locator(".swagger-ui .info .title")).to_contain_text("slidewatch")
    expect(
        page.locator(".opblock-summary-path", has_text="/api/v1/sites/{site_id}/gis").first
    ).to_be_visible()
    assert outside == []

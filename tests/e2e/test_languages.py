"""The page in Japanese and back in English: chosen in the top bar (kept over a reload), or
by the browser's own languages; dates in the locale's format, in the site's time zone."""

import os
import re
import time

import httpx
from playwright.sync_api import Browser, Page, expect

from tests.e2e.conftest import ARTIFACTS, LAPTOP, REPO, USER, App, compare_uploaded
from tests.e2e.test_map import sign_in
from worker.simulator.dsm_pair import DsmPairPaths

SITE = "Hillside"


def compared_site(app: App, pair: DsmPairPaths) -> int:
    """A site in Asia/Tokyo with two DSM surveys and their finished comparison (made over
    the API: this test is about the page's words, not the upload)."""
    with httpx.Client(base_url=f"{app.url}/api/v1", timeout=60) as api:
        token = api.post("/auth/sign-in", json=USER).json()["token"]
        api.headers["Authorization"] = f"Bearer {token}"
        site = api.post("/sites", json={"name": SITE, "timezone": "Asia/Tokyo"}).json()
        compare_uploaded(
            api,
            site["id"],
            [
                (pair.pre, "2026-06-01T01:00:00Z", "June flight"),
                (pair.post, "2026-07-01T01:00:00Z", "July flight"),
            ],
        )
        return site["id"]


def report_languages(app: App, site: int) -> list[str | None]:
    """The language of each report of the site, as the API lists them."""
    with httpx.Client(base_url=f"{app.url}/api/v1", timeout=60) as api:
        token = api.post("/auth/sign-in", json=USER).json()["token"]
        api.headers["Authorization"] = f"Bearer {token}"
        return [r["language"] for r in api.get(f"/sites/{site}/reports").json()]


def page_shot(page: Page, name: str) -> None:
    """The whole window as a test artifact, and into the docs when asked for."""
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / f"{name}.png"))
    docs = os.environ.get("SLIDEWATCH_DOCS_SCREENSHOTS")
    if docs:
        page.screenshot(path=str(REPO / docs / f"{name}.png"))


def choose_language(page: Page, code: str) -> None:
    # The top bar's selector (a site's page also has the language of its reports).
    page.locator("#language-select").select_option(code)
    expect(page.locator("html")).to_have_attribute("lang", code)


def test_the_page_switches_to_japanese_and_back(
    page: Page, app_server: App, dsm_pair: DsmPairPaths
) -> None:
    site = compared_site(app_server, dsm_pair)
    sign_in(page, app_server)  # English: the test browser's language is en-GB
    expect(page.locator("html")).to_have_attribute("lang", "en")
    page.goto(f"{app_server.url}/#/sites/{site}")
    expect(page.get_by_role("heading", name=SITE, level=1)).to_be_visible()
    expect(page.get_by_role("button", name="Detection 1")).to_be_visible(timeout=30_000)
    surveys = page.locator(".survey-list")
    expect(surveys).to_contain_text("1 Jun 2026, 10:00 GMT+9")
    page.get_by_role("button", name="Detection 1").click()
    expect(page.locator(".leaflet-popup-content")).to_contain_text("Volume lost")
    page_shot(page, "page-site-en")

    # Japanese from the top bar: the page is drawn again at once, in the site's time zone.
    choose_language(page, "ja")
    expect(page.get_by_role("button", name="ログアウト")).to_be_visible()
    expect(page.get_by_role("heading", name="2 つの測量を比較")).to_be_visible()
    expect(page.get_by_role("button", name="比較を実行")).to_be_visible()
    expect(surveys).to_contain_text("2026年6月1日 10:00 JST")
    expect(surveys).to_contain_text("処理済み")
    expect(page.get_by_role("button", name="検出 1")).to_be_visible(timeout=30_000)
    comparison = page.locator(".comparison").first
    expect(comparison).to_contain_text("完了")
    expect(comparison).to_contain_text(re.compile(r"\d+ 件の検出、[\d,.]+ m²、減少量 [\d,.]+ m³"))
    expect(page.locator(".map-legends summary")).to_have_text("凡例")
    page.get_by_role("button", name="検出 1").click()
    popup = page.locator(".leaflet-popup-content")
    expect(popup).to_contain_text("面積")
    expect(popup.get_by_role("button", name="地すべりと確認")).to_be_visible()
    page_shot(page, "page-site-ja")
    # A report made from the Japanese page is written in Japanese (the site's is English).
    page.locator("#reports-section summary").click()
    page.get_by_role("button", name="報告書を今すぐ作成").click()
    deadline = time.monotonic() + 30
    while report_languages(app_server, site) != ["ja"]:
        assert time.monotonic() < deadline, report_languages(app_server, site)
        time.sleep(0.5)

    # Kept over a reload, and on every page.
    page.reload()
    expect(page.locator("html")).to_have_attribute("lang", "ja")
    expect(page.get_by_role("heading", name="測量", exact=True)).to_be_visible()
    page.get_by_role("link", name="現場", exact=True).click()
    expect(page.get_by_role("heading", name="現場", level=1)).to_be_visible()
    expect(page.get_by_role("heading", name="新しい現場")).to_be_visible()
    since = re.compile(r"\d{4}年\d{1,2}月\d{1,2}日 登録")
    expect(page.locator("#site-list")).to_contain_text(since)

    # And back in English.
    choose_language(page, "en")
    expect(page.get_by_role("heading", name="Sites", level=1)).to_be_visible()
    expect(page.get_by_role("button", name="Sign out")).to_be_visible()
    since = re.compile(r"since \d{1,2} [A-Z][a-z]{2} \d{4}")
    expect(page.locator("#site-list")).to_contain_text(since)
    page.get_by_role("link", name=SITE).click()
    expect(surveys).to_contain_text("1 Jun 2026, 10:00 GMT+9")
    expect(page.get_by_role("button", name="Compare", exact=True)).to_be_visible()


def test_a_japanese_browser_gets_the_page_in_japanese(browser: Browser, app_server: App) -> None:
    context = browser.new_context(viewport=LAPTOP, locale="ja-JP", timezone_id="Asia/Tokyo")
    page = context.new_page()
    try:
        page.goto(app_server.url + "/")
        expect(page.locator("html")).to_have_attribute("lang", "ja")
        expect(page.get_by_role("heading", name="ログイン")).to_be_visible()
        page.get_by_label("ユーザー名").fill(USER["username"])
        page.get_by_label("パスワード").fill(USER["password"])
        page.get_by_role("button", name="ログイン").click()
        expect(page.get_by_role("heading", name="現場", level=1)).to_be_visible()
        expect(page.locator("#language-select")).to_have_value("ja")
    finally:
        context.close()

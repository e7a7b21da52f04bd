"""A site's language (its scheduled reports and alert e-mails) chosen on its page, next to
its time zone, from the languages the server has reports in."""

import httpx
from playwright.sync_api import Page, expect

from tests.e2e.conftest import USER, App
from tests.e2e.test_map import create_site, sign_in


def test_the_site_language_is_chosen_on_its_page(page: Page, app_server: App) -> None:
    sign_in(page, app_server)
    create_site(page, "Language slope")
    page.get_by_role("button", name="Change time zone").click()
    choice = page.get_by_label("Language of reports and e-mails")
    expect(choice).to_have_value("en")
    expect(choice.locator("option")).to_have_text(["English", "日本語"])
    choice.select_option("ja")
    # The heading is on the page before the save as after it: wait for the save itself.
    with page.expect_response(
        lambda r: r.request.method == "PATCH" and "/api/v1/sites/" in r.url
    ) as saved:
        page.get_by_role("button", name="Save time zone and language").click()
    assert saved.value.ok
    expect(page.get_by_role("heading", name="Language slope", level=1)).to_be_visible()

    with httpx.Client(base_url=f"{app_server.url}/api/v1", timeout=30) as api:
        token = api.post("/auth/sign-in", json=USER).json()["token"]
        sites = api.get("/sites", headers={"Authorization": f"Bearer {token}"}).json()
    [site] = [s for s in sites if s["name"] == "Language slope"]
    assert site["language"] == "ja" and site["timezone"] == "Europe/Rome"
    page.get_by_role("button", name="Change time zone").click()
    expect(page.get_by_label("Language of reports and e-mails")).to_have_value("ja")

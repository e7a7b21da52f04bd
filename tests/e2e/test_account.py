"""The account page end to end: API tokens made with an expiry and revoked, the password
changed; and a sign-in form that tells of a lock-out after too many wrong passwords."""

from playwright.sync_api import Page, expect
from sqlalchemy.orm import Session

from backend.db.session import make_engine
from backend.services.users import create_user
from tests.e2e.conftest import App, shot


def _user(app: App, username: str, password: str) -> None:
    """A user of this test alone: a lock-out must not reach the others' accounts."""
    engine = make_engine(app.settings.resolved_database_url)
    with engine.begin() as connection, Session(bind=connection) as session:
        create_user(session, username, password)
        session.flush()
    engine.dispose()


def _sign_in(page: Page, app: App, username: str, password: str) -> None:
    page.goto(app.url + "/")
    expect(page.get_by_role("heading", name="Sign in")).to_be_visible()
    page.get_by_label("User name").fill(username)
    page.get_by_label("Password").fill(password)
    page.get_by_role("button", name="Sign in").click()


def test_tokens_are_made_and_revoked_and_the_password_changed(page: Page, app_server: App) -> None:
    _user(app_server, "luca", "pendio-franoso")
    _sign_in(page, app_server, "luca", "pendio-franoso")
    page.get_by_role("link", name="Account").click()
    expect(page.get_by_role("heading", name="API tokens")).to_be_visible()
    expect(page.locator("#token-rows")).to_contain_text("map session of luca")

    page.get_by_label("New token for").fill("qgis")
    page.get_by_label("Valid for (days)").fill("7")
    page.get_by_role("button", name="Make token").click()
    expect(page.locator("#new-token-value")).to_contain_text("sw_")
    qgis = page.locator("#token-rows tr", has_text="qgis")
    expect(qgis).to_contain_text("API")
    shot(page, "account-tokens")
    page.get_by_role("button", name="Revoke qgis").click()
    expect(page.locator("#token-rows tr", has_text="qgis")).to_have_count(0)

    page.get_by_label("Current password").fill("pendio-franoso")
    page.get_by_label("New password").fill("password123")
    page.get_by_role("button", name="Change password").click()
    expect(page.locator("#password-change-error")).to_contain_text("most common passwords")
    page.get_by_label("New password").fill("frana-attiva-2026")
    page.get_by_role("button", name="Change password").click()
    expect(page.get_by_role("status")).to_contain_text("Your password is changed")
    _sign_in(page, app_server, "luca", "frana-attiva-2026")
    expect(page.get_by_role("heading", name="Sites")).to_be_visible()


def test_a_lock_out_is_told_on_the_sign_in_form_and_after_it(page: Page, app_server: App) -> None:
    _user(app_server, "nina", "argine-sicuro")
    for _ in range(2):
        _sign_in(page, app_server, "nina", "a-wrong-guess")
        expect(page.locator("#password-error")).to_contain_text("wrong user name or password")
    _sign_in(page, app_server, "nina", "argine-sicuro")
    # The failures before it are told once, after signing in.
    expect(page.locator("#sign-in-notice")).to_contain_text("2 failed sign-ins to your account")
    page.get_by_role("button", name="Sign out").click()
    expect(page.get_by_role("heading", name="Sign in")).to_be_visible()
    for _ in range(5):
        _sign_in(page, app_server, "nina", "a-wrong-guess")
        expect(page.locator("#password-error")).to_contain_text("wrong user name or password")
    _sign_in(page, app_server, "nina", "argine-sicuro")
    expect(page.locator("#password-error")).to_contain_text(
        "too many failed sign-ins to the account 'nina'"
    )
    shot(page, "sign-in-locked")


def test_the_platform_administrator_creates_disables_and_enables_a_user(
    page: Page, app_server: App
) -> None:
    import httpx

    from backend.db.tokens import create_token

    engine = make_engine(app_server.settings.resolved_database_url)
    with engine.begin() as connection, Session(bind=connection) as session:
        token = create_token(session, "platform")  # as `slidewatch create-token` makes it
        session.flush()
    engine.dispose()
    page.goto(app_server.url + "/")
    page.get_by_text("Sign in with an API token instead").click()
    page.get_by_label("API token").fill(token)
    page.get_by_role("button", name="Use token").click()
    page.get_by_role("link", name="Account").click()
    expect(page.get_by_role("heading", name="Users", exact=True)).to_be_visible()

    page.get_by_label("New user's name").fill("kenji")
    page.get_by_label("Full name").fill("Kenji Sato")
    page.get_by_label("Password (at least 8 characters").fill("shamen-kansoku")
    page.get_by_role("button", name="Create user").click()
    row = page.locator("table.users tr", has_text="kenji")
    expect(row).to_contain_text("Kenji Sato")

    def signs_in() -> int:
        body = {"username": "kenji", "password": "shamen-kansoku"}
        return httpx.post(f"{app_server.url}/api/v1/auth/sign-in", json=body).status_code

    assert signs_in() == 200
    row.get_by_role("button", name="Disable").click()
    expect(row).to_contain_text("disabled")
    assert signs_in() == 401
    row.get_by_role("button", name="Enable").click()
    expect(row).not_to_contain_text("disabled")
    assert signs_in() == 200


def test_signing_in_draws_the_sites_page_once(page: Page, app_server: App) -> None:
    """Signing in leads to the sites page once: drawn a second time (by the hash change
    the sign-in makes, after the page was drawn for it), the page dropped what the user
    had begun typing into the new-site form."""
    _user(app_server, "ada", "versante-stabile")
    page.goto(app_server.url + "/")
    expect(page.get_by_role("heading", name="Sign in")).to_be_visible()
    page.evaluate(
        """() => {
            window.siteFormsDrawn = 0;
            new MutationObserver((records) => {
                for (const r of records)
                    for (const n of r.addedNodes)
                        if (n.querySelector?.("#new-site")) window.siteFormsDrawn += 1;
            }).observe(document.getElementById("app"), { childList: true, subtree: true });
        }"""
    )
    page.get_by_label("User name").fill("ada")
    page.get_by_label("Password").fill("versante-stabile")
    page.get_by_role("button", name="Sign in").click()
    expect(page.get_by_role("heading", name="Sites")).to_be_visible()
    page.get_by_label("Name").fill("North scarp")
    page.wait_for_load_state("networkidle")
    page.wait_for_timeout(500)
    assert page.evaluate("window.siteFormsDrawn") == 1
    expect(page.get_by_label("Name")).to_have_value("North scarp")

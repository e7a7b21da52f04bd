// Sign in with a user name and password, or with an API token of the platform.

import { ApiError, api, session } from "../api";
import { escapeHtml } from "../format";
import { serverText, t } from "../i18n";
import { languageSelectHtml, wireLanguageSelect } from "../i18n/selector";
import type { WhoAmI } from "../types";
import { keepSignInNotice } from "./header";

export function renderSignIn(app: HTMLElement, done: () => void): void {
  const notice = sessionStorage.getItem("slidewatch.notice");
  sessionStorage.removeItem("slidewatch.notice");
  app.innerHTML = `
    <main id="main" class="sign-in">
      <p class="language-row">${languageSelectHtml()}</p>
      <h1>slidewatch</h1>
      <p class="lead">${t("signIn.lead")}</p>
      ${notice ? `<p class="notice" role="status">${escapeHtml(notice)}</p>` : ""}
      <form id="password-form" aria-labelledby="password-title">
        <h2 id="password-title">${t("signIn.title")}</h2>
        <label for="username">${t("signIn.username")}</label>
        <input id="username" name="username" autocomplete="username" required>
        <label for="password">${t("signIn.password")}</label>
        <input id="password" name="password" type="password" autocomplete="current-password" required>
        <button type="submit">${t("signIn.submit")}</button>
        <p class="error" role="alert" id="password-error"></p>
      </form>
      <details>
        <summary>${t("signIn.withToken")}</summary>
        <form id="token-form">
          <label for="token">${t("signIn.tokenLabel", { makeRun: "<code>make run</code>", createToken: "<code>slidewatch create-token</code>" })}</label>
          <input id="token" name="token" autocomplete="off" required>
          <button type="submit">${t("signIn.useToken")}</button>
          <p class="error" role="alert" id="token-error"></p>
        </form>
      </details>
    </main>`;
  const passwordForm = app.querySelector("#password-form") as HTMLFormElement;
  passwordForm.addEventListener("submit", async (event) => {
    event.preventDefault();
    const error = app.querySelector("#password-error") as HTMLElement;
    error.textContent = "";
    const data = new FormData(passwordForm);
    try {
      const body = await api<{ token: string; user: { username: string }; notice: string | null }>("auth/sign-in", {
        method: "POST",
        body: JSON.stringify({ username: data.get("username"), password: data.get("password") }),
      });
      session.set(body.token, body.user.username);
      keepSignInNotice(body.notice);
      done();
    } catch (e) {
      error.textContent = e instanceof ApiError ? t("signIn.refused", { reason: refusal(e) }) : t("error.unreachable");
    }
  });
  const tokenForm = app.querySelector("#token-form") as HTMLFormElement;
  tokenForm.addEventListener("submit", async (event) => {
    event.preventDefault();
    const error = app.querySelector("#token-error") as HTMLElement;
    const token = String(new FormData(tokenForm).get("token")).trim();
    session.set(token, "");
    try {
      const who = await api<WhoAmI>("auth/me");
      session.set(token, `token ${who.name}`);
      done();
    } catch (e) {
      session.clear();
      error.textContent = e instanceof ApiError ? t("signIn.refused", { reason: refusal(e) }) : t("error.unreachable");
    }
  });
  wireLanguageSelect(app);
  (app.querySelector("#username") as HTMLInputElement).focus();
}

/** Why a sign-in was refused: the server's own words (marked as such on a page in another
 * language); the page's lead ("sign in again") would only repeat what the form says. */
function refusal(e: ApiError): string {
  return e.detail === null ? e.message : serverText(e.detail);
}

// Your account: the API tokens you hold (make one that expires, revoke any), your password.

import { ApiError, api, getJson, postJson, session } from "../api";
import { PeoplePanel } from "../components/people";
import { escapeHtml, formatDateTime } from "../format";
import { t } from "../i18n";
import type { ApiTokenInfo, NewApiToken } from "../types";
import { header, wireSignOut } from "./header";

const when = (iso: string | null) => (iso ? escapeHtml(formatDateTime(iso, "UTC")) : "—");

function tokenRows(tokens: ApiTokenInfo[]): string {
  if (!tokens.length) return `<tr><td colspan="6" class="muted">${t("account.noTokens")}</td></tr>`;
  return tokens
    .map(
      (token) => `<tr data-token="${token.id}">
        <td>${escapeHtml(token.name)}${token.current ? ` <em>${t("account.thisOne")}</em>` : ""}</td>
        <td>${token.kind === "session" ? t("account.kindSession") : t("account.kindApi")}</td>
        <td><code>${escapeHtml(token.prefix)}…</code></td>
        <td>${when(token.last_used_at)}</td>
        <td>${token.expires_at ? when(token.expires_at) : t("account.never")}</td>
        <td><button type="button" class="revoke" data-id="${token.id}" aria-label="${escapeHtml(t("account.revokeNamed", { name: token.name }))}">${t("account.revoke")}</button></td>
      </tr>`,
    )
    .join("");
}

export async function renderAccount(app: HTMLElement): Promise<void> {
  const isUser = !(session.who ?? "").startsWith("token ");
  app.innerHTML = `${header(`<a href="#/">${t("sites.title")}</a> › <span>${t("account.title")}</span>`)}
    <main id="main" class="account">
      <h1>${t("account.title")}</h1>
      <section class="card" aria-labelledby="tokens-title">
        <h2 id="tokens-title">${t("account.tokens")}</h2>
        <p class="muted">${t("account.tokensHelp")}</p>
        <table class="tokens"><thead><tr><th>${t("account.colName")}</th><th>${t("account.colKind")}</th><th>${t("account.colPrefix")}</th>
          <th>${t("account.colLastUsed")}</th><th>${t("account.colExpires")}</th><th></th></tr></thead>
          <tbody id="token-rows"><tr><td colspan="6">${t("common.loading")}</td></tr></tbody></table>
        <form id="new-token">
          <label for="token-name">${t("account.newTokenFor")}</label><input id="token-name" required maxlength="200">
          <label for="token-days">${t("account.validDays")}</label><input id="token-days" type="number" min="1" max="365" value="30" required>
          <button type="submit">${t("account.makeToken")}</button>
          <p class="error" role="alert" id="token-error"></p>
          <p class="notice" id="token-secret" hidden></p>
        </form>
      </section>
      <section class="card" aria-labelledby="people-title">
        <h2 id="people-title">${t("account.people")}</h2>
        <div id="people"><p>${t("common.loading")}</p></div>
      </section>
      ${
        isUser
          ? `<form id="password-change" class="card" aria-labelledby="password-change-title">
        <h2 id="password-change-title">${t("account.password")}</h2>
        <label for="current-password">${t("account.currentPassword")}</label>
        <input id="current-password" type="password" autocomplete="current-password" required>
        <label for="new-password">${t("account.newPassword")}</label>
        <input id="new-password" type="password" autocomplete="new-password" required>
        <button type="submit">${t("account.changePassword")}</button>
        <p class="error" role="alert" id="password-change-error"></p>
      </form>`
          : ""
      }
    </main>`;
  wireSignOut(app);
  const rows = app.querySelector("#token-rows") as HTMLElement;
  const refresh = async () => {
    rows.innerHTML = tokenRows(await getJson<ApiTokenInfo[]>("auth/tokens"));
  };
  rows.addEventListener("click", async (event) => {
    const button = (event.target as HTMLElement).closest("button.revoke") as HTMLButtonElement | null;
    if (!button) return;
    await api(`auth/tokens/${button.dataset.id}`, { method: "DELETE" });
    await refresh();
  });
  const form = app.querySelector("#new-token") as HTMLFormElement;
  form.addEventListener("submit", async (event) => {
    event.preventDefault();
    const error = app.querySelector("#token-error") as HTMLElement;
    const secret = app.querySelector("#token-secret") as HTMLElement;
    error.textContent = "";
    try {
      const made = await postJson<NewApiToken>("auth/tokens", {
        name: (app.querySelector("#token-name") as HTMLInputElement).value.trim(),
        days: Number((app.querySelector("#token-days") as HTMLInputElement).value),
      });
      secret.hidden = false;
      secret.innerHTML = t("account.copyNow", { token: `<code id="new-token-value">${escapeHtml(made.token)}</code>` });
      await refresh();
    } catch (e) {
      error.textContent = e instanceof ApiError ? e.message : t("error.unreachable");
    }
  });
  app.querySelector("#password-change")?.addEventListener("submit", async (event) => {
    event.preventDefault();
    const error = app.querySelector("#password-change-error") as HTMLElement;
    error.textContent = "";
    try {
      await postJson("auth/password", {
        current_password: (app.querySelector("#current-password") as HTMLInputElement).value,
        new_password: (app.querySelector("#new-password") as HTMLInputElement).value,
      });
      // Every session ends with the old password, this one too.
      sessionStorage.setItem("slidewatch.notice", t("account.passwordChanged"));
      session.clear();
      location.hash = "#/"; // the sign-in form, which shows the notice
    } catch (e) {
      error.textContent = e instanceof ApiError ? e.message : t("error.unreachable");
    }
  });
  await Promise.all([refresh(), new PeoplePanel(app.querySelector("#people") as HTMLElement).load()]);
}

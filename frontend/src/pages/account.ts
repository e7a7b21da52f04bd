// Your account: the API tokens you hold (make one that expires, revoke any), your password.

import { ApiError, api, getJson, postJson, session } from "../api";
import { PeoplePanel } from "../components/people";
import { escapeHtml, formatDateTime } from "../format";
import type { ApiTokenInfo, NewApiToken } from "../types";
import { header, wireSignOut } from "./header";

const when = (iso: string | null) => (iso ? escapeHtml(formatDateTime(iso, "UTC")) : "—");

function tokenRows(tokens: ApiTokenInfo[]): string {
  if (!tokens.length) return `<tr><td colspan="6" class="muted">No tokens.</td></tr>`;
  return tokens
    .map(
      (t) => `<tr data-token="${t.id}">
        <td>${escapeHtml(t.name)}${t.current ? " <em>(this one)</em>" : ""}</td>
        <td>${t.kind === "session" ? "sign-in" : "API"}</td>
        <td><code>${escapeHtml(t.prefix)}…</code></td>
        <td>${when(t.last_used_at)}</td>
        <td>${t.expires_at ? when(t.expires_at) : "never"}</td>
        <td><button type="button" class="revoke" data-id="${t.id}" aria-label="Revoke ${escapeHtml(t.name)}">Revoke</button></td>
      </tr>`,
    )
    .join("");
}

export async function renderAccount(app: HTMLElement): Promise<void> {
  const isUser = !(session.who ?? "").startsWith("token ");
  app.innerHTML = `${header(`<a href="#/">Sites</a> › <span>Account</span>`)}
    <main id="main" class="account">
      <h1>Account</h1>
      <section class="card" aria-labelledby="tokens-title">
        <h2 id="tokens-title">API tokens</h2>
        <p class="muted">For QGIS, GDAL and scripts. Each expires; revoke one as soon as it leaks.</p>
        <table class="tokens"><thead><tr><th>Name</th><th>Kind</th><th>Starts with</th>
          <th>Last used (UTC)</th><th>Expires (UTC)</th><th></th></tr></thead>
          <tbody id="token-rows"><tr><td colspan="6">Loading…</td></tr></tbody></table>
        <form id="new-token">
          <label for="token-name">New token for</label><input id="token-name" required maxlength="200">
          <label for="token-days">Valid for (days)</label><input id="token-days" type="number" min="1" max="365" value="30" required>
          <button type="submit">Make token</button>
          <p class="error" role="alert" id="token-error"></p>
          <p class="notice" id="token-secret" hidden></p>
        </form>
      </section>
      <section class="card" aria-labelledby="people-title">
        <h2 id="people-title">Members and users</h2>
        <div id="people"><p>Loading…</p></div>
      </section>
      ${
        isUser
          ? `<form id="password-change" class="card" aria-labelledby="password-change-title">
        <h2 id="password-change-title">Password</h2>
        <label for="current-password">Current password</label>
        <input id="current-password" type="password" autocomplete="current-password" required>
        <label for="new-password">New password (at least 8 characters, not a common one)</label>
        <input id="new-password" type="password" autocomplete="new-password" required>
        <button type="submit">Change password</button>
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
      secret.innerHTML = `Copy it now, it is not shown again: <code id="new-token-value">${escapeHtml(made.token)}</code>`;
      await refresh();
    } catch (e) {
      error.textContent = e instanceof ApiError ? e.message : "The server cannot be reached.";
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
      sessionStorage.setItem("slidewatch.notice", "Your password is changed: sign in with the new one.");
      session.clear();
      location.hash = "#/"; // the sign-in form, which shows the notice
    } catch (e) {
      error.textContent = e instanceof ApiError ? e.message : "The server cannot be reached.";
    }
  });
  await Promise.all([refresh(), new PeoplePanel(app.querySelector("#people") as HTMLElement).load()]);
}

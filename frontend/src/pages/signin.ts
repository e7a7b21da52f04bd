// Sign in with a user name and password, or with an API token of the platform.

import { ApiError, api, session } from "../api";
import { escapeHtml } from "../format";
import type { WhoAmI } from "../types";
import { keepSignInNotice } from "./header";

export function renderSignIn(app: HTMLElement, done: () => void): void {
  const notice = sessionStorage.getItem("slidewatch.notice");
  sessionStorage.removeItem("slidewatch.notice");
  app.innerHTML = `
    <main id="main" class="sign-in">
      <h1>slidewatch</h1>
      <p class="lead">Landslides found by comparing drone surveys over time.</p>
      ${notice ? `<p class="notice" role="status">${escapeHtml(notice)}</p>` : ""}
      <form id="password-form" aria-labelledby="password-title">
        <h2 id="password-title">Sign in</h2>
        <label for="username">User name</label>
        <input id="username" name="username" autocomplete="username" required>
        <label for="password">Password</label>
        <input id="password" name="password" type="password" autocomplete="current-password" required>
        <button type="submit">Sign in</button>
        <p class="error" role="alert" id="password-error"></p>
      </form>
      <details>
        <summary>Sign in with an API token instead</summary>
        <form id="token-form">
          <label for="token">API token (from <code>make run</code> or <code>slidewatch create-token</code>)</label>
          <input id="token" name="token" autocomplete="off" required>
          <button type="submit">Use token</button>
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
      error.textContent = e instanceof ApiError ? `Not signed in: ${e.message}.` : "The server cannot be reached.";
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
      error.textContent = e instanceof ApiError ? `Not signed in: ${e.message}.` : "The server cannot be reached.";
    }
  });
  (app.querySelector("#username") as HTMLInputElement).focus();
}

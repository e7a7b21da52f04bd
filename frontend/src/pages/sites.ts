// The list of sites, and a form for a new one.

import { ApiError, getJson, postJson } from "../api";
import { timeZoneField } from "../components/tools";
import { escapeHtml, formatDate } from "../format";
import { t } from "../i18n";
import type { Site } from "../types";
import { header, wireSignOut } from "./header";

export async function renderSites(app: HTMLElement): Promise<void> {
  app.innerHTML = `${header(`<span>${t("sites.title")}</span>`)}
    <main id="main" class="sites">
      <h1>${t("sites.title")}</h1>
      <ul class="site-list" id="site-list" aria-live="polite"><li>${t("common.loading")}</li></ul>
      <form id="new-site" class="card">
        <h2>${t("sites.new")}</h2>
        <label for="site-name">${t("sites.name")}</label><input id="site-name" required maxlength="200">
        <label for="site-description">${t("sites.description")}</label><input id="site-description">
        ${timeZoneField(
          "site-timezone",
          Intl.DateTimeFormat().resolvedOptions().timeZone || "UTC",
          t("sites.timeZone"),
        )}
        <button type="submit">${t("sites.create")}</button>
        <p class="error" role="alert" id="site-error"></p>
      </form>
    </main>`;
  wireSignOut(app);
  // The form works at once; the list arrives when it arrives.
  const form = app.querySelector("#new-site") as HTMLFormElement;
  form.addEventListener("submit", async (event) => {
    event.preventDefault();
    const value = (id: string) => (app.querySelector(`#${id}`) as HTMLInputElement).value.trim();
    try {
      const site = await postJson<Site>("sites", {
        name: value("site-name"),
        description: value("site-description"),
        timezone: value("site-timezone"),
      });
      location.hash = `#/sites/${site.id}`;
    } catch (e) {
      (app.querySelector("#site-error") as HTMLElement).textContent =
        e instanceof ApiError ? e.message : t("error.unreachable");
    }
  });
  const list = app.querySelector("#site-list") as HTMLElement;
  const sites = await getJson<Site[]>("sites");
  list.innerHTML = sites.length
    ? sites
        .map(
          (s) => `<li><a href="#/sites/${s.id}">${escapeHtml(s.name)}</a>
            <span class="muted">${escapeHtml(s.description)} · ${escapeHtml(s.timezone)} · ${t("sites.since", { date: formatDate(s.created_at, s.timezone) })}</span></li>`,
        )
        .join("")
    : `<li>${t("sites.none")}</li>`;
}

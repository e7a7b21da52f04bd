// Monitoring schedules: a cron expression built from plain choices (or typed), the next
// five times it runs as the server computes them, in the site's time zone; then a report
// of the site's latest comparison at each of those times.

import { ApiError, api, getJson, postJson } from "../api";
import { escapeHtml, formatDateTime } from "../format";
import { currentLocale, t } from "../i18n";
import { failure } from "./tools";

interface Schedule {
  id: number;
  name: string;
  cron: string;
  timezone: string;
  enabled: boolean;
  next_run_at: string;
  last_run_at: string | null;
}

interface Preview {
  next_runs: string[];
}

export type Frequency = "hourly" | "daily" | "weekly" | "monthly" | "custom";

export interface CronChoice {
  frequency: Frequency;
  minute: number;
  hour: number;
  weekday: number; // 0 Sunday … 6 Saturday, as cron
  monthday: number;
}

/** The weekdays' names in the page's language, Sunday first as cron counts them
 * (4 January 2026 was a Sunday). */
export function weekdayNames(): string[] {
  const format = new Intl.DateTimeFormat(currentLocale(), { weekday: "long", timeZone: "UTC" });
  return Array.from({ length: 7 }, (_, i) => format.format(new Date(Date.UTC(2026, 0, 4 + i))));
}

/** The cron expression of a choice; null for "custom" (typed by hand). */
export function cronOf(c: CronChoice): string | null {
  switch (c.frequency) {
    case "hourly":
      return `${c.minute} * * * *`;
    case "daily":
      return `${c.minute} ${c.hour} * * *`;
    case "weekly":
      return `${c.minute} ${c.hour} * * ${c.weekday}`;
    case "monthly":
      return `${c.minute} ${c.hour} ${c.monthday} * *`;
    default:
      return null;
  }
}

const options = (values: Array<[string | number, string]>, selected: string | number) =>
  values.map(([v, t]) => `<option value="${v}"${String(v) === String(selected) ? " selected" : ""}>${t}</option>`).join("");
const range = (n: number, from = 0) => Array.from({ length: n }, (_, i) => [i + from, String(i + from).padStart(2, "0")] as [number, string]);

export class SchedulesPanel {
  private previewTimer: number | undefined;
  private previewCount = 0;

  constructor(
    private readonly box: HTMLElement,
    private readonly siteId: number,
    private readonly timeZone: string,
  ) {
    box.innerHTML = `<form id="schedule-form">
        <label for="schedule-frequency">${t("schedules.make")}</label>
        <select id="schedule-frequency">${options(
          [
            ["hourly", t("schedules.hourly")],
            ["daily", t("schedules.daily")],
            ["weekly", t("schedules.weekly")],
            ["monthly", t("schedules.monthly")],
            ["custom", t("schedules.custom")],
          ],
          "weekly",
        )}</select>
        <span data-part="weekday"><label for="schedule-weekday">${t("schedules.on")}</label><select id="schedule-weekday">${options(
          weekdayNames().map((d, i) => [i, d] as [number, string]),
          1,
        )}</select></span>
        <span data-part="monthday"><label for="schedule-monthday">${t("schedules.onDay")}</label><select id="schedule-monthday">${options(range(28, 1), 1)}</select></span>
        <span data-part="hour"><label for="schedule-hour">${t("schedules.atHour")}</label><select id="schedule-hour">${options(range(24), 6)}</select></span>
        <label for="schedule-minute">${t("schedules.minute")}</label><select id="schedule-minute">${options(
          range(12).map(([m]) => [m * 5, String(m * 5).padStart(2, "0")] as [number, string]),
          0,
        )}</select>
        <label for="schedule-cron">${t("schedules.cron", { zone: escapeHtml(timeZone) })}</label>
        <input id="schedule-cron" required maxlength="120" spellcheck="false" autocomplete="off">
        <label for="schedule-name">${t("schedules.name")}</label><input id="schedule-name" maxlength="200">
        <p class="muted">${t("schedules.nextRuns")}</p>
        <ol class="next-runs" id="schedule-next" aria-live="polite"></ol>
        <p class="error" role="alert" id="schedule-error"></p>
        <button type="submit">${t("schedules.save")}</button>
      </form>
      <ul class="plain" id="schedule-list"></ul>`;
    const form = box.querySelector("#schedule-form") as HTMLFormElement;
    form.addEventListener("change", (event) => {
      if ((event.target as HTMLElement).id !== "schedule-cron") this.fromChoices();
    });
    this.field("schedule-cron").addEventListener("input", () => {
      this.field("schedule-frequency").value = "custom";
      this.showParts();
      this.schedulePreview();
    });
    form.addEventListener("submit", (event) => {
      event.preventDefault();
      void this.save();
    });
    box.querySelector("#schedule-list")?.addEventListener("click", (event) => {
      const target = event.target as HTMLElement;
      const remove = target.closest<HTMLElement>("[data-delete-schedule]")?.dataset.deleteSchedule;
      const toggle = target.closest<HTMLElement>("[data-toggle-schedule]");
      if (remove) void this.act(() => api(`sites/${siteId}/schedules/${remove}`, { method: "DELETE" }));
      if (toggle)
        void this.act(() =>
          api(`sites/${siteId}/schedules/${toggle.dataset.toggleSchedule}`, {
            method: "PATCH",
            body: JSON.stringify({ enabled: toggle.dataset.enabled !== "true" }),
          }),
        );
    });
    this.fromChoices();
  }

  private field(id: string): HTMLInputElement {
    return this.box.querySelector(`#${id}`) as HTMLInputElement;
  }

  private choice(): CronChoice {
    const n = (id: string) => Number(this.field(id).value);
    return {
      frequency: this.field("schedule-frequency").value as Frequency,
      minute: n("schedule-minute"),
      hour: n("schedule-hour"),
      weekday: n("schedule-weekday"),
      monthday: n("schedule-monthday"),
    };
  }

  private showParts(): void {
    const frequency = this.field("schedule-frequency").value;
    const shown: Record<string, boolean> = {
      weekday: frequency === "weekly",
      monthday: frequency === "monthly",
      hour: frequency !== "hourly" && frequency !== "custom",
    };
    for (const part of this.box.querySelectorAll<HTMLElement>("[data-part]")) part.hidden = !shown[part.dataset.part ?? ""];
  }

  private fromChoices(): void {
    this.showParts();
    const cron = cronOf(this.choice());
    if (cron) this.field("schedule-cron").value = cron;
    this.schedulePreview();
  }

  private schedulePreview(): void {
    window.clearTimeout(this.previewTimer);
    this.previewTimer = window.setTimeout(() => void this.preview(), 250);
  }

  /** The next five runs, from the server (the code that will run the schedule). */
  async preview(): Promise<void> {
    const asked = ++this.previewCount;
    const cron = this.field("schedule-cron").value.trim();
    const list = this.box.querySelector("#schedule-next") as HTMLElement;
    const error = this.box.querySelector("#schedule-error") as HTMLElement;
    const query = new URLSearchParams({ cron, timezone: this.timeZone, count: "5" });
    try {
      const preview = await getJson<Preview>(`sites/${this.siteId}/schedules/preview?${query}`);
      if (asked !== this.previewCount) return; // a newer expression was typed meanwhile
      error.textContent = "";
      list.innerHTML = preview.next_runs.map((t) => `<li>${escapeHtml(formatDateTime(t, this.timeZone))}</li>`).join("");
    } catch (e) {
      if (asked !== this.previewCount) return;
      list.innerHTML = "";
      error.textContent = failure(e);
    }
  }

  private async act(action: () => Promise<unknown>): Promise<void> {
    try {
      await action();
      await this.load();
    } catch (e) {
      (this.box.querySelector("#schedule-error") as HTMLElement).textContent = failure(e);
    }
  }

  async save(): Promise<void> {
    await this.act(() =>
      postJson(`sites/${this.siteId}/schedules`, {
        cron: this.field("schedule-cron").value.trim(),
        timezone: this.timeZone,
        name: this.field("schedule-name").value.trim(),
      }),
    );
  }

  async load(): Promise<void> {
    const list = this.box.querySelector("#schedule-list") as HTMLElement;
    try {
      const schedules = await getJson<Schedule[]>(`sites/${this.siteId}/schedules`);
      list.innerHTML = schedules.length
        ? schedules
            .map(
              (s) => `<li data-schedule="${s.id}"><code>${escapeHtml(s.cron)}</code> ${escapeHtml(s.name)}
                <span class="muted">${s.enabled ? t("schedules.next", { when: escapeHtml(formatDateTime(s.next_run_at, this.timeZone)) }) : t("schedules.paused")}${
                  s.last_run_at ? t("schedules.last", { when: escapeHtml(formatDateTime(s.last_run_at, this.timeZone)) }) : ""
                }${s.timezone !== this.timeZone ? t("schedules.cronZone", { zone: escapeHtml(s.timezone) }) : ""}</span>
                <span class="row-actions"><button type="button" data-toggle-schedule="${s.id}" data-enabled="${s.enabled}">${s.enabled ? t("schedules.pause") : t("schedules.resume")}</button>
                <button type="button" data-delete-schedule="${s.id}">${t("schedules.delete", { id: s.id })}</button></span></li>`,
            )
            .join("")
        : `<li class="muted">${t("schedules.none")}</li>`;
    } catch (e) {
      // Said rather than an empty list, e.g. a role too small to see schedules.
      list.innerHTML = `<li class="error">${escapeHtml(e instanceof ApiError ? e.message : failure(e))}</li>`;
    }
  }
}

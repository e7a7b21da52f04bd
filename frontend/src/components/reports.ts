// Reports of a site: make one now (of the comparison on the map, or the latest), see each
// one's state until it is ready, download it as PDF or HTML.

import { getJson, postJson } from "../api";
import { escapeHtml, formatDateTime } from "../format";
import { currentLanguage, t } from "../i18n";
import { download, failure } from "./tools";

export interface Report {
  id: number;
  comparison_id: number | null;
  schedule_id: number | null;
  trigger: string;
  status: "queued" | "running" | "succeeded" | "failed";
  summary: { detections?: number } | null;
  error: string | null;
  created_at: string;
  finished_at: string | null;
  pdf_url: string | null;
  html_url: string | null;
}

const POLL_MS = 1500;

export function reportLine(r: Report, timeZone: string): string {
  const how = r.trigger === "schedule" ? t("reports.scheduled", { schedule: String(r.schedule_id) }) : t("reports.onDemand");
  const state =
    r.status === "succeeded"
      ? r.summary?.detections != null
        ? t("reports.readyWith", { found: t("count.detections", { count: r.summary.detections }) })
        : t("reports.ready")
      : r.status === "failed"
        ? t("reports.failed", { reason: r.error ?? t("common.noReason") })
        : t(r.status === "queued" ? "reports.queued" : "reports.running");
  return t("reports.line", {
    id: r.id,
    comparison: r.comparison_id ?? "—",
    how,
    when: formatDateTime(r.created_at, timeZone),
    state,
  });
}

export class ReportsPanel {
  private comparisonId: number | null = null;
  private timer: number | undefined;

  constructor(
    private readonly box: HTMLElement,
    private readonly siteId: number,
    private readonly timeZone: string,
    /** Languages the server writes reports in: a report made here is in the page's when it is one. */
    private readonly reportLanguages: readonly string[] = [],
  ) {
    box.innerHTML = `<p class="muted" id="report-for"></p>
      <button type="button" id="make-report">${t("reports.make")}</button>
      <p class="error" role="alert" id="report-error"></p>
      <ul class="plain" id="report-list" aria-live="polite"></ul>`;
    box.querySelector("#make-report")?.addEventListener("click", () => void this.make());
    box.querySelector("#report-list")?.addEventListener("click", (event) => {
      const button = (event.target as HTMLElement).closest<HTMLButtonElement>("button[data-url]");
      if (!button) return;
      download(button.dataset.url ?? "", button.dataset.name ?? "report").catch((e) => this.fail(e));
    });
  }

  /** The comparison a new report is about (the one on the map); null: the site's latest. */
  setComparison(id: number | null): void {
    this.comparisonId = id;
    (this.box.querySelector("#report-for") as HTMLElement).textContent =
      id == null ? t("reports.forLatest") : t("reports.forShown", { id });
  }

  private fail(e: unknown): void {
    (this.box.querySelector("#report-error") as HTMLElement).textContent = failure(e);
  }

  async make(): Promise<void> {
    (this.box.querySelector("#report-error") as HTMLElement).textContent = "";
    try {
      const language = this.reportLanguages.includes(currentLanguage()) ? currentLanguage() : undefined;
      await postJson<Report>(`sites/${this.siteId}/reports`, { comparison_id: this.comparisonId, language });
      await this.load();
    } catch (e) {
      this.fail(e);
    }
  }

  async load(): Promise<void> {
    window.clearTimeout(this.timer);
    let reports: Report[];
    try {
      reports = await getJson<Report[]>(`sites/${this.siteId}/reports`);
    } catch (e) {
      this.fail(e);
      return;
    }
    const list = this.box.querySelector("#report-list") as HTMLElement;
    list.innerHTML = reports.length
      ? reports
          .slice(0, 20)
          .map(
            (r) => `<li data-report="${r.id}" data-status="${r.status}">${escapeHtml(reportLine(r, this.timeZone))}
              ${r.pdf_url ? `<button type="button" class="link-button" data-url="${escapeHtml(r.pdf_url)}" data-name="slidewatch-report-${r.id}.pdf">PDF</button>` : ""}
              ${r.html_url ? `<button type="button" class="link-button" data-url="${escapeHtml(r.html_url)}" data-name="slidewatch-report-${r.id}.html">HTML</button>` : ""}</li>`,
          )
          .join("")
      : `<li class="muted">${t("reports.none")}</li>`;
    // Until every report is finished, ask again; the worker makes one in seconds.
    if (reports.some((r) => r.status === "queued" || r.status === "running")) {
      this.timer = window.setTimeout(() => void this.load(), POLL_MS);
    }
  }

  close(): void {
    window.clearTimeout(this.timer);
  }
}

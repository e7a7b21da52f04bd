// Processing jobs of the site with their stages, live through Server-Sent Events; a failed
// job shows why and can be retried. The latest jobs first, the whole history on demand,
// each with its stages' logs (what happened in each attempt, as the worker kept it).

import { ApiError, authHeaders, postJson } from "../api";
import { escapeHtml, formatDateTime, formatPercent } from "../format";
import { streamEvents } from "../sse";
import { type MessageKey, serverText, serverWords, speaksServerLanguage, t } from "../i18n";
import type { Job, StageRun } from "../types";

const FINAL = new Set(["succeeded", "failed"]);

// One name for one thing: stage names and their help are the pipeline's own (from the
// API), in the page's language where its catalogue has them (serverWords).
export function jobTitle(job: Job): string {
  if (job.kind === "comparison") return t("jobs.comparison", { id: job.comparison_id ?? "" }).trim();
  if (job.kind === "reconstruction") return t("jobs.reconstruction", { id: job.survey_id ?? "" }).trim();
  return t("jobs.other", { kind: serverWords(`jobKind.${job.kind}`, job.kind) });
}

/** A stage's name, and what it does in one line, in the page's language. */
export const stageName = (stage: StageRun) => serverWords(`stage.${stage.stage}`, stage.stage);
export const stageHelp = (stage: StageRun) => serverWords(`stageHelp.${stage.stage}`, stage.help ?? "");

const STATES = new Set(["queued", "pending", "running", "succeeded", "failed"]);
/** A job's or stage's state in words; one the page does not know as the API says it. */
const stateWord = (state: string) => (STATES.has(state) ? t(`state.${state}` as MessageKey) : state);

const RECENT = 8;

function stageLogsHtml(job: Job, open: boolean): string {
  const stages = job.stages
    .filter((s) => s.log?.length)
    .map((s) => `<h4>${escapeHtml(stageName(s))}</h4><pre class="stage-log" lang="en">${escapeHtml(s.log.join("\n"))}</pre>`)
    .join("");
  if (!stages) return "";
  // The lines are the worker's, in English: a page in another language says so.
  const note = speaksServerLanguage() ? "" : `<p class="muted">${t("jobs.logsOriginal")}</p>`;
  return `<details class="job-log" data-log="${job.id}"${open ? " open" : ""}><summary>${t("jobs.logs", { id: job.id })}</summary>${note}${stages}</details>`;
}

export class JobsPanel {
  private jobs = new Map<number, Job>();
  private streams = new Map<number, AbortController>();
  private showAll = false;
  /** Logs left open stay open when the job's next event redraws the panel. */
  private openLogs = new Set<number>();

  constructor(
    private readonly box: HTMLElement,
    private readonly siteId: number,
    private readonly timeZone: string,
    private readonly onFinished: (job: Job) => void,
  ) {
    box.addEventListener("click", (event) => {
      const button = (event.target as HTMLElement).closest<HTMLButtonElement>("button[data-retry]");
      if (button) void this.retry(Number(button.dataset.retry), button);
      if ((event.target as HTMLElement).closest("button[data-all-jobs]")) {
        this.showAll = !this.showAll;
        this.render();
      }
    });
    box.addEventListener(
      "toggle",
      (event) => {
        const details = event.target as HTMLDetailsElement;
        if (!details.dataset?.log) return;
        if (details.open) this.openLogs.add(Number(details.dataset.log));
        else this.openLogs.delete(Number(details.dataset.log));
      },
      true, // toggle does not bubble
    );
  }

  show(jobs: Job[]): void {
    for (const job of jobs) this.jobs.set(job.id, job);
    this.render();
    for (const job of jobs) if (!FINAL.has(job.state)) this.follow(job.id);
  }

  private follow(jobId: number): void {
    if (this.streams.has(jobId)) return;
    const controller = new AbortController();
    this.streams.set(jobId, controller);
    void streamEvents(`/api/v1/sites/${this.siteId}/jobs/${jobId}/events`, {
      headers: authHeaders(),
      signal: controller.signal,
      onEvent: (event) => {
        if (event.event !== "job") return;
        const job = JSON.parse(event.data) as Job;
        this.jobs.set(job.id, job);
        this.render();
        if (FINAL.has(job.state)) this.onFinished(job);
      },
      onEnd: () => this.streams.delete(jobId),
    }).catch(() => this.streams.delete(jobId));
  }

  private async retry(jobId: number, button: HTMLButtonElement): Promise<void> {
    button.disabled = true;
    try {
      const job = await postJson<Job>(`sites/${this.siteId}/jobs/${jobId}/retry`, {});
      this.jobs.set(job.id, job);
      this.render();
      this.follow(job.id);
    } catch (e) {
      button.disabled = false;
      const error = this.box.querySelector(`[data-job="${jobId}"] .retry-error`);
      if (error) error.textContent = e instanceof ApiError ? e.message : t("error.unreachable");
    }
  }

  private render(): void {
    const all = [...this.jobs.values()].sort((a, b) => b.id - a.id);
    const jobs = this.showAll ? all : all.slice(0, RECENT);
    if (!jobs.length) {
      this.box.innerHTML = `<p class="muted">${t("jobs.none")}</p>`;
      return;
    }
    this.box.innerHTML = jobs
      .map((job) => {
        const stages = job.stages
          .map(
            (s) => `<li class="stage stage-${s.state}">
              <label><span class="stage-name">${escapeHtml(stageName(s))}</span> <span class="muted">${escapeHtml(stageHelp(s))}</span>
              <progress max="1" value="${s.state === "succeeded" ? 1 : s.progress}" aria-label="${escapeHtml(t("jobs.stageProgress", { stage: stageName(s) }))}">${formatPercent(s.progress)}</progress></label>
              <span class="stage-state">${stateWord(s.state)}${s.attempts > 1 ? t("jobs.attempt", { n: s.attempts }) : ""}</span>
            </li>`,
          )
          .join("");
        const failed = job.state === "failed";
        return `<article class="job job-${job.state}" data-job="${job.id}" aria-live="polite">
          <h3>${escapeHtml(jobTitle(job))} <span class="job-state">${stateWord(job.state)}</span> <span class="muted">${formatPercent(job.progress)}</span></h3>
          <p class="muted">${t("jobs.queuedAt", { when: formatDateTime(job.created_at, this.timeZone) })}${job.finished_at ? t("jobs.finishedAt", { when: formatDateTime(job.finished_at, this.timeZone) }) : ""}</p>
          <ol class="stages">${stages}</ol>
          ${stageLogsHtml(job, this.openLogs.has(job.id))}
          ${failed ? `<p class="error" role="alert">${t("jobs.failed", { reason: escapeHtml(job.error ? serverText(job.error) : t("common.noReason")) })}</p>
            <button type="button" data-retry="${job.id}">${t("jobs.retry", { id: job.id })}</button><p class="error retry-error"></p>` : ""}
        </article>`;
      })
      .join("") +
      (all.length > RECENT
        ? `<button type="button" data-all-jobs>${this.showAll ? t("jobs.showLatest", { count: RECENT }) : t("jobs.showAll", { count: all.length })}</button>`
        : "");
  }

  close(): void {
    for (const controller of this.streams.values()) controller.abort();
    this.streams.clear();
  }
}

// The site's surveys on a time axis, in the site's time zone.

import { escapeHtml, formatDate, formatDateTime, formatMetres, parseApiTime } from "../format";
import { type MessageKey, t } from "../i18n";
import type { Survey } from "../types";
import { surveyQualityHtml, surveyWarningsHtml } from "../warnings";

/** Position (0..1) of each survey along the axis; one survey sits in the middle. */
export function timelinePositions(surveys: Survey[]): number[] {
  const times = surveys.map((s) => parseApiTime(s.captured_at).getTime());
  const min = Math.min(...times);
  const max = Math.max(...times);
  return times.map((t) => (max > min ? (t - min) / (max - min) : 0.5));
}

const STATUS_WORDS: Record<Survey["status"], MessageKey> = {
  receiving: "survey.receiving",
  uploaded: "survey.uploaded",
  processing: "survey.processing",
  ready: "survey.ready",
  failed: "survey.failed",
};

const KIND_WORDS: Record<Survey["kind"], MessageKey> = {
  dsm: "survey.kindDsm",
  video: "survey.kindVideo",
  images: "survey.kindImages",
};

export function renderTimeline(surveys: Survey[], timeZone: string): string {
  if (!surveys.length) return `<p class="muted">${t("survey.none")}</p>`;
  const positions = timelinePositions(surveys);
  const marks = surveys
    .map(
      (s, i) => `<li class="mark status-${s.status}" style="left:${(positions[i] * 100).toFixed(2)}%"
        title="${escapeHtml(s.name)}, ${formatDateTime(s.captured_at, timeZone)}"><span class="visually-hidden">${escapeHtml(s.name)}</span></li>`,
    )
    .join("");
  const first = formatDate(surveys[0].captured_at, timeZone);
  const last = formatDate(surveys[surveys.length - 1].captured_at, timeZone);
  const rows = surveys
    .map(
      (s) => `<li class="survey" data-survey-id="${s.id}">
        <span class="name">${escapeHtml(s.name)}</span>
        <span class="when">${formatDateTime(s.captured_at, timeZone)}</span>
        <span class="what">${t(KIND_WORDS[s.kind])} ·
          <span class="status">${t(STATUS_WORDS[s.status])}</span>${s.resolution_m ? ` · ${t("survey.pixels", { size: formatMetres(s.resolution_m) })}` : ""}</span>
        ${s.error ? `<span class="error">${escapeHtml(s.error)}</span>` : ""}
        <span class="row-actions">
          <button type="button" data-rename-survey="${s.id}">${t("survey.rename", { name: escapeHtml(s.name) })}</button>
          ${s.status === "failed" && s.kind !== "dsm" ? `<button type="button" data-fix-survey="${s.id}">${t("survey.replaceFiles", { name: escapeHtml(s.name) })}</button>` : ""}
          <button type="button" data-delete-survey="${s.id}">${t("survey.delete", { name: escapeHtml(s.name) })}</button>
        </span>
        ${surveyQualityHtml(s.quality)}
        ${surveyWarningsHtml(s.warnings, s.quality)}
      </li>`,
    )
    .join("");
  return `<div class="timeline" role="img" aria-label="${escapeHtml(t("survey.timeline", { first, last }))}"><ol class="axis">${marks}</ol>
      <div class="axis-labels"><span>${first}</span><span>${last}</span></div></div>
    <ol class="survey-list">${rows}</ol>`;
}

// What reading a survey's files and reconstructing it had to skip or assume (the API's
// `warnings`), as notices on the page: under each uploaded file, and in a survey's row;
// and a survey's quality verdict (`quality`) when it missed its bounds.

import { escapeHtml } from "./format";
import { t } from "./i18n";
import type { SurveyQuality } from "./types";

/** A warning as shown under its file, naming the file: the flight-log readers begin with
 * it ("flight.SRT: 3 of 546 blocks unreadable and skipped (line 11: …)"); a warning that
 * does not gets it, so that a line read on its own still says which file it is about. */
export function fileWarningText(fileName: string, warning: string): string {
  const named = warning.startsWith(`${fileName}:`) || warning.startsWith(`${fileName},`);
  return named ? warning : `${fileName}: ${warning}`;
}

/** "1 warning", "3 warnings". */
export function warningCount(count: number): string {
  return t("count.warnings", { count });
}

/** A notice under each file that was read with warnings; "" when none was. */
export function fileWarningsHtml(files: ReadonlyArray<{ name: string; warnings: readonly string[] }>): string {
  return files
    .filter((f) => f.warnings.length)
    .map(
      (f) => `<div class="notice file-warnings" role="note" data-file="${escapeHtml(f.name)}">
        <p>${t("warnings.fileReadWith", { file: `<strong>${escapeHtml(f.name)}</strong>`, warnings: warningCount(f.warnings.length) })}</p>
        <ul>${f.warnings.map((w) => `<li>${escapeHtml(fileWarningText(f.name, w))}</li>`).join("")}</ul></div>`,
    )
    .join("");
}

/** A survey's warnings (its files' and its reconstruction report's) in its row: the count
 * always in sight, each warning one click away; "" when there are none. */
export function surveyWarningsHtml(warnings: readonly string[]): string {
  if (!warnings.length) return "";
  return `<details class="notice survey-warnings">
      <summary>${t("warnings.surveyReadWith", { warnings: warningCount(warnings.length) })}</summary>
      <ul>${warnings.map((w) => `<li>${escapeHtml(w)}</li>`).join("")}</ul></details>`;
}

/** The line a survey that missed its quality bounds shows in sight: the first failed
 * check's message, and how many more failed; null when it passed or has no verdict yet. */
export function qualitySummary(quality: SurveyQuality | null | undefined): string | null {
  const failed = quality?.checks.filter((c) => !c.passed) ?? [];
  if (!quality || quality.passed || !failed.length) return null;
  const more = failed.length > 1 ? t("warnings.andMore", { count: failed.length - 1 }) : "";
  return t("warnings.missedBounds", { message: failed[0].message, more });
}

/** A survey's quality verdict in its row: nothing while it passed, else a mark with the
 * first failed check in sight and every check, passed or missed, one click away. */
export function surveyQualityHtml(quality: SurveyQuality | null | undefined): string {
  const summary = qualitySummary(quality);
  if (!quality || summary === null) return "";
  const checks = quality.checks
    .map(
      (c) => `<li class="${c.passed ? "check-passed" : "check-failed"}" data-check="${escapeHtml(c.name)}">
        <strong>${c.passed ? t("warnings.met") : t("warnings.missed")}</strong> ${escapeHtml(c.message)}</li>`,
    )
    .join("");
  return `<details class="notice survey-quality" role="note">
      <summary>${escapeHtml(summary)}</summary>
      <ul>${checks}</ul></details>`;
}

/** A comparison's warnings (each quality check its surveys missed) under its row. */
export function comparisonWarningsHtml(warnings: readonly string[] | undefined): string {
  if (!warnings?.length) return "";
  return `<details class="notice comparison-warnings" role="note">
      <summary>${t("warnings.comparisonMissed", { count: warnings.length })}</summary>
      <ul>${warnings.map((w) => `<li>${escapeHtml(w)}</li>`).join("")}</ul></details>`;
}

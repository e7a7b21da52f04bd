// What reading a survey's files and reconstructing it had to skip or assume (the API's
// `warnings`), as notices on the page: under each uploaded file, and in a survey's row;
// and a survey's quality verdict (`quality`) when it missed its bounds.

import { escapeHtml } from "./format";
import { serverMessage, serverWords, speaksServerLanguage, t } from "./i18n";
import type { QualityCheck, SurveyQuality } from "./types";

/** A warning as shown under its file, naming the file: the flight-log readers begin with
 * it ("flight.SRT: 3 of 546 blocks unreadable and skipped (line 11: …)"); a warning that
 * does not gets it, so that a line read on its own still says which file it is about. */
export function fileWarningText(fileName: string, warning: string): string {
  const named = warning.startsWith(`${fileName}:`) || warning.startsWith(`${fileName},`);
  return named ? warning : `${fileName}: ${warning}`;
}

/** On a page in another language than the server's: the note that the warnings listed
 * are the server's own words, in English ("" on an English page). */
function originalNote(): string {
  return speaksServerLanguage() ? "" : `<p class="muted server-original">${t("warnings.serverOriginal")}</p>`;
}

/** A list of the server's words, marked as English for the browser and screen readers. */
function serverList(items: readonly string[]): string {
  return `<ul lang="en">${items.map((w) => `<li>${escapeHtml(w)}</li>`).join("")}</ul>`;
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
        ${originalNote()}${serverList(f.warnings.map((w) => fileWarningText(f.name, w)))}</div>`,
    )
    .join("");
}

/** A survey's warnings (its files' and its reconstruction report's) in its row: the count
 * always in sight, each warning one click away; "" when there are none. */
export function surveyWarningsHtml(warnings: readonly string[], quality?: SurveyQuality | null): string {
  // A missed check's message is also among the warnings (the report lists it there);
  // where the page words that check itself (surveyQualityHtml), its English copy is left out.
  const worded = new Set((quality?.checks ?? []).filter((c) => checkMessage(c) !== null).map((c) => c.message));
  warnings = warnings.filter((w) => !worded.has(w));
  if (!warnings.length) return "";
  return `<details class="notice survey-warnings">
      <summary>${t("warnings.surveyReadWith", { warnings: warningCount(warnings.length) })}</summary>
      ${originalNote()}${serverList(warnings)}</details>`;
}

/** A quality check by its name in the page's language; its message (the server's words)
 * on an English page, and for a check the catalogue does not know. */
const checkWords = (check: QualityCheck) => serverWords(`quality.${check.name}`, check.message);

/** A check's message in the page's language from its key and figures; null on a page in
 * the server's language, or where the check has no key or the catalogue lacks it. */
export function checkMessage(check: QualityCheck): string | null {
  if (!check.text) return null;
  const figures: Record<string, string | number> = { ...check.text.figures };
  figures.where = figures.segment ? t("qualityText.segment", { n: figures.segment }) : "";
  if (check.text.key === "timeOffset.matched") {
    const source = serverMessage(`qualityText.offsetSource.${figures.source}`, {}) ?? String(figures.source);
    const refined = figures.refined ? (serverMessage(`qualityText.offsetRefined.${figures.refined}`, {}) ?? "") : "";
    figures.how = source + refined;
  }
  if (figures.dropped !== undefined) figures.count = Number(figures.dropped);
  return serverMessage(`qualityText.${check.text.key}`, figures);
}

/** The line a survey that missed its quality bounds shows in sight: the first failed
 * check's message, and how many more failed; null when it passed or has no verdict yet. */
export function qualitySummary(quality: SurveyQuality | null | undefined): string | null {
  const failed = quality?.checks.filter((c) => !c.passed) ?? [];
  if (!quality || quality.passed || !failed.length) return null;
  const more = failed.length > 1 ? t("warnings.andMore", { count: failed.length - 1 }) : "";
  return t("warnings.missedBounds", { message: checkMessage(failed[0]) ?? checkWords(failed[0]), more });
}

/** A survey's quality verdict in its row: nothing while it passed, else a mark with the
 * first failed check in sight and every check, passed or missed, one click away. */
export function surveyQualityHtml(quality: SurveyQuality | null | undefined): string {
  const summary = qualitySummary(quality);
  if (!quality || summary === null) return "";
  const checks = quality.checks
    .map(
      (c) => `<li class="${c.passed ? "check-passed" : "check-failed"}" data-check="${escapeHtml(c.name)}">
        <strong>${c.passed ? t("warnings.met") : t("warnings.missed")}</strong> ${checkLineHtml(c)}</li>`,
    )
    .join("");
  return `<details class="notice survey-quality" role="note">
      <summary>${escapeHtml(summary)}</summary>
      <ul>${checks}</ul></details>`;
}

/** A check's line after its mark: its message; on a page in another language, the check
 * by its name in that language first, its message as the server's English after it. */
function checkLineHtml(check: QualityCheck): string {
  const message = escapeHtml(check.message);
  if (speaksServerLanguage()) return message;
  const own = checkMessage(check);
  if (own !== null) return t("warnings.checkLine", { check: escapeHtml(checkWords(check)), message: escapeHtml(own) });
  const name = checkWords(check);
  const original = `<span lang="en">${message}</span>`;
  return name === check.message ? original : t("warnings.checkLine", { check: escapeHtml(name), message: original });
}

/** A comparison's warnings (each quality check its surveys missed) under its row. */
export function comparisonWarningsHtml(warnings: readonly string[] | undefined): string {
  if (!warnings?.length) return "";
  return `<details class="notice comparison-warnings" role="note">
      <summary>${t("warnings.comparisonMissed", { count: warnings.length })}</summary>
      ${originalNote()}${serverList(warnings)}</details>`;
}

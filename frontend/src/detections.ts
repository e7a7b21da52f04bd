// How detections look on the map and what their popup says.

import { escapeHtml, formatArea, formatDate, formatDateTime, formatFixed, formatMetres, formatVolume, percent } from "./format";
import { t } from "./i18n";
import type { DetectionProperties } from "./types";
import { formatLatLon, formatUtm, toUtm } from "./map/utm";

/** Yellow (unsure) to dark red (sure); more opaque the surer the detection. */
export function scoreColor(score: number): string {
  const s = Math.max(0, Math.min(1, score));
  const stops: Array<[number, [number, number, number]]> = [
    // Violets, light to dark: apart from Δh's blue (lost) and red (gained), so a red
    // outline never reads as "gained" and a sure detection never as a loss.
    [0, [221, 214, 254]],
    [0.5, [139, 92, 246]],
    [1, [76, 29, 149]],
  ];
  const i = s <= 0.5 ? 0 : 1;
  const [s0, c0] = stops[i];
  const [s1, c1] = stops[i + 1];
  const t = (s - s0) / (s1 - s0);
  const rgb = c0.map((c, k) => Math.round(c + (c1[k] - c) * t));
  return `rgb(${rgb.join(", ")})`;
}

export interface PathStyle {
  color: string;
  weight: number;
  fillColor: string;
  fillOpacity: number;
  opacity: number;
}

export function detectionStyle(score: number, selected = false): PathStyle {
  const color = scoreColor(score);
  return {
    color: selected ? "#00e5ff" : color,
    weight: selected ? 4 : 2.5,
    fillColor: color,
    // Light enough for the Δh colours beneath to show through.
    fillOpacity: 0.08 + 0.22 * Math.max(0, Math.min(1, score)),
    opacity: 1,
  };
}

export function cellStyle(): PathStyle {
  return { color: "#7b2cbf", weight: 1, fillColor: "#7b2cbf", fillOpacity: 0.12, opacity: 0.8 };
}


/** "812 m² (95 %: 760–870 m²)": the value and its 95 % interval, the unit said once when
 * both ends share it; the value alone when the method gives no interval (cnn). */
export function withInterval(
  value: number,
  interval: [number, number] | null | undefined,
  format: (v: number) => string,
): string {
  if (!interval) return format(value);
  const [low, high] = interval.map(format);
  const unit = / \S+$/.exec(high)?.[0];
  const lowText = unit && low.endsWith(unit) ? low.slice(0, -unit.length) : low;
  return t("popup.withInterval", { value: format(value), level: percent(95), low: lowText, high });
}

/** The popup's table: every number with its unit; text escaped. */
/** A detection's popup; `position` (lat, lon of its centre) adds where to walk to, with a
 * button that copies it. */
export function detectionPopupHtml(
  id: number,
  p: DetectionProperties,
  timeZone: string,
  position?: [number, number],
): string {
  const u = p.uncertainty ?? {};
  const rows: Array<[string, string]> = [
    [t("popup.area"), withInterval(p.area_m2, u.area_m2_ci95, formatArea)],
    [t("popup.volumeLost"), withInterval(p.volume_loss_m3, u.volume_loss_m3_ci95, formatVolume)],
    [t("popup.volumeGained"), withInterval(p.volume_gain_m3, u.volume_gain_m3_ci95, formatVolume)],
    [t("popup.maxDh"), formatMetres(p.max_abs_dh_m)],
    ...(u.lod_m != null ? [[t("popup.lod", { level: percent(95) }), formatMetres(u.lod_m)] as [string, string]] : []),
    [t("popup.score"), formatFixed(p.score, 2)],
    [t("popup.method"), p.method],
    [t("popup.modelVersion"), p.model_version ?? t("popup.noModel")],
  ];
  const latest = p.feedback?.latest;
  const verdict = latest
    ? t(latest.verdict === "confirmed" ? "popup.confirmedBy" : "popup.falseAlarmBy", {
        author: latest.author,
        when: formatDateTime(latest.at, timeZone),
      })
    : t("popup.noVerdict");
  return `
    <div class="popup" data-detection-id="${id}">
      <h3>${t("popup.title", { label: p.label ?? id })}</h3>
      <table>${rows.map(([k, v]) => `<tr><th scope="row">${escapeHtml(k)}</th><td>${escapeHtml(v)}</td></tr>`).join("")}</table>
      ${position ? positionHtml(position) : ""}
      <p><button type="button" data-history>${t("popup.history")}</button></p>
      <div data-role="history" aria-live="polite"></div>
      <p class="verdict">${t("popup.verdict", {
        verdict: `<span data-role="verdict">${escapeHtml(verdict)}</span>`,
        confirmed: p.feedback?.confirmed ?? 0,
        falseAlarms: p.feedback?.false_alarm ?? 0,
      })}</p>
      <div class="verdict-buttons">
        <button type="button" data-verdict="confirmed">${t("popup.confirm")}</button>
        <button type="button" data-verdict="false_alarm">${t("popup.falseAlarm")}</button>
      </div>
    </div>`;
}

/** The centre as latitude/longitude and UTM, and a "Copy position" button whose text to
 * copy is in its data-position. */
export function positionHtml([lat, lon]: [number, number]): string {
  const text = `${formatLatLon(lat, lon)} (UTM ${formatUtm(toUtm(lat, lon))})`;
  return `<p class="position" data-role="position">${t("popup.centre", { position: escapeHtml(formatLatLon(lat, lon)) })}<br>UTM ${escapeHtml(
    formatUtm(toUtm(lat, lon)),
  )}<br><button type="button" data-position="${escapeHtml(text)}">${t("popup.copyPosition")}</button></p>`;
}

/** One detection of the same ground in another comparison (GET …/detections/{id}/history). */
export interface HistoryEntry {
  comparison_id: number;
  detection_id: number;
  label: number;
  pre_captured_at: string;
  post_captured_at: string;
  area_m2: number;
  volume_loss_m3: number;
  volume_gain_m3: number;
  max_abs_dh_m: number;
  score: number;
  overlap: number;
  this: boolean;
}

/** The detection's ground over time: one row per comparison that found something there. */
export function historyHtml(entries: HistoryEntry[], timeZone: string): string {
  if (entries.length <= 1) return `<p class="muted">${t("history.none")}</p>`;
  const rows = entries
    .map(
      (e) => `<tr${e.this ? ' class="this"' : ""}><td>${t("history.detection", { comparison: e.comparison_id, label: e.label })}</td><td>${escapeHtml(formatDate(e.pre_captured_at, timeZone))} → ${escapeHtml(
        formatDate(e.post_captured_at, timeZone),
      )}${e.this ? ` ${t("history.thisOne")}` : ""}</td><td>${escapeHtml(formatArea(e.area_m2))}</td><td>${escapeHtml(formatVolume(e.volume_loss_m3))}</td><td>${percent(Math.round(e.overlap * 100))}</td></tr>`,
    )
    .join("");
  return `<table class="history"><thead><tr><th scope="col">${t("history.comparison")}</th><th scope="col">${t("history.surveys")}</th><th scope="col">${t("history.area")}</th><th scope="col">${t("history.lost")}</th><th scope="col">${t("history.overlap")}</th></tr></thead><tbody>${rows}</tbody></table>`;
}


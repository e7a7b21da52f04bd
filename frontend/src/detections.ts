// How detections look on the map and what their popup says.

import { escapeHtml, formatArea, formatDate, formatDateTime, formatMetres, formatVolume } from "./format";
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

const VERDICT_WORDS = { confirmed: "confirmed landslide", false_alarm: "false alarm" } as const;

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
  return `${format(value)} (95 %: ${lowText}–${high})`;
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
    ["Area", withInterval(p.area_m2, u.area_m2_ci95, formatArea)],
    ["Volume lost", withInterval(p.volume_loss_m3, u.volume_loss_m3_ci95, formatVolume)],
    ["Volume gained", withInterval(p.volume_gain_m3, u.volume_gain_m3_ci95, formatVolume)],
    ["Max |Δh|", formatMetres(p.max_abs_dh_m)],
    ...(u.lod_m != null ? [["LoD (95 %)", formatMetres(u.lod_m)] as [string, string]] : []),
    ["Score", p.score.toFixed(2)],
    ["Method", p.method],
    ["Model version", p.model_version ?? "none (the method runs no model)"],
  ];
  const latest = p.feedback?.latest;
  const verdict = latest
    ? `${VERDICT_WORDS[latest.verdict]} by ${latest.author}, ${formatDateTime(latest.at, timeZone)}`
    : "no verdict yet";
  return `
    <div class="popup" data-detection-id="${id}">
      <h3>Detection ${p.label ?? id}</h3>
      <table>${rows.map(([k, v]) => `<tr><th scope="row">${escapeHtml(k)}</th><td>${escapeHtml(v)}</td></tr>`).join("")}</table>
      ${position ? positionHtml(position) : ""}
      <p><button type="button" data-history>History of this ground</button></p>
      <div data-role="history" aria-live="polite"></div>
      <p class="verdict">Verdict: <span data-role="verdict">${escapeHtml(verdict)}</span>
        (${p.feedback?.confirmed ?? 0} confirmed, ${p.feedback?.false_alarm ?? 0} false alarm)</p>
      <div class="verdict-buttons">
        <button type="button" data-verdict="confirmed">Confirm landslide</button>
        <button type="button" data-verdict="false_alarm">False alarm</button>
      </div>
    </div>`;
}

/** The centre as latitude/longitude and UTM, and a "Copy position" button whose text to
 * copy is in its data-position. */
export function positionHtml([lat, lon]: [number, number]): string {
  const text = `${formatLatLon(lat, lon)} (UTM ${formatUtm(toUtm(lat, lon))})`;
  return `<p class="position" data-role="position">Centre: ${escapeHtml(formatLatLon(lat, lon))}<br>UTM ${escapeHtml(
    formatUtm(toUtm(lat, lon)),
  )}<br><button type="button" data-position="${escapeHtml(text)}">Copy position</button></p>`;
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
  if (entries.length <= 1) return `<p class="muted">No other comparison of this site found a change here.</p>`;
  const rows = entries
    .map(
      (e) => `<tr${e.this ? ' class="this"' : ""}><td>${e.comparison_id} · detection ${e.label}</td><td>${escapeHtml(formatDate(e.pre_captured_at, timeZone))} → ${escapeHtml(
        formatDate(e.post_captured_at, timeZone),
      )}${e.this ? " (this one)" : ""}</td><td>${escapeHtml(formatArea(e.area_m2))}</td><td>${escapeHtml(formatVolume(e.volume_loss_m3))}</td><td>${Math.round(e.overlap * 100)} %</td></tr>`,
    )
    .join("");
  return `<table class="history"><thead><tr><th scope="col">Comparison</th><th scope="col">Surveys</th><th scope="col">Area</th><th scope="col">Lost</th><th scope="col">Overlap</th></tr></thead><tbody>${rows}</tbody></table>`;
}


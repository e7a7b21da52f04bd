// Numbers with their units in the page's locale, and times in the site's time zone.

import { currentLocale, t } from "./i18n";

const nf = (digits: number) =>
  new Intl.NumberFormat(currentLocale(), { maximumFractionDigits: digits, minimumFractionDigits: 0 });

/** A number in the page's locale with up to `digits` decimals. */
export function formatNumber(value: number, digits = 2): string {
  return nf(digits).format(value);
}

/** A number with exactly `digits` decimals ("0.85"), as a score is shown. */
export function formatFixed(value: number, digits: number): string {
  return new Intl.NumberFormat(currentLocale(), { maximumFractionDigits: digits, minimumFractionDigits: digits }).format(value);
}

export function formatMetres(value: number | null | undefined, digits = 2): string {
  return value == null || !Number.isFinite(value) ? "—" : t("unit.metres", { value: nf(digits).format(value) });
}

export function formatArea(m2: number | null | undefined): string {
  if (m2 == null || !Number.isFinite(m2)) return "—";
  if (Math.abs(m2) >= 100_000) return t("unit.hectares", { value: nf(2).format(m2 / 10_000) });
  return t("unit.squareMetres", { value: nf(m2 < 100 ? 1 : 0).format(m2) });
}

export function formatVolume(m3: number | null | undefined): string {
  return m3 == null || !Number.isFinite(m3) ? "—" : t("unit.cubicMetres", { value: nf(m3 < 100 ? 1 : 0).format(m3) });
}

export function formatBytes(bytes: number): string {
  const units = ["B", "KB", "MB", "GB", "TB"];
  let value = bytes;
  let unit = 0;
  while (value >= 1000 && unit < units.length - 1) {
    value /= 1000;
    unit += 1;
  }
  return t("unit.bytes", { value: nf(unit === 0 ? 0 : 1).format(value), unit: units[unit] });
}

/** A whole percentage, rounded down (a progress never shows 100 before it is done). */
export function formatPercent(fraction: number): string {
  return percent(Math.floor(Math.max(0, Math.min(1, fraction)) * 100));
}

/** A percentage already in hundredths ("95 %", "95%" in Japanese). */
export function percent(value: number): string {
  return t("unit.percent", { value: nf(0).format(value) });
}

/** "22 Nov 2026, 14:05 CET" (en-GB), "2026年11月22日 14:05 JST" (ja) in the site's time zone. */
export function formatDateTime(iso: string | null | undefined, timeZone: string): string {
  if (!iso) return "—";
  const date = parseApiTime(iso);
  return new Intl.DateTimeFormat(currentLocale(), {
    timeZone,
    day: "numeric",
    month: "short",
    year: "numeric",
    hour: "2-digit",
    minute: "2-digit",
    hourCycle: "h23",
    timeZoneName: "short",
  }).format(date);
}

export function formatDate(iso: string, timeZone: string): string {
  return new Intl.DateTimeFormat(currentLocale(), {
    timeZone,
    day: "numeric",
    month: "short",
    year: "numeric",
  }).format(parseApiTime(iso));
}

/** Times from the API are UTC; SQLite gives them back without an offset. */
export function parseApiTime(iso: string): Date {
  const hasZone = /([zZ]|[+-]\d\d:?\d\d)$/.test(iso);
  return new Date(hasZone ? iso : `${iso}Z`);
}

function zoneOffsetMs(utcMs: number, timeZone: string): number {
  const parts = new Intl.DateTimeFormat("en-US", {
    timeZone,
    hourCycle: "h23",
    year: "numeric",
    month: "2-digit",
    day: "2-digit",
    hour: "2-digit",
    minute: "2-digit",
    second: "2-digit",
  }).formatToParts(new Date(utcMs));
  const get = (type: string) => Number(parts.find((p) => p.type === type)?.value);
  const wall = Date.UTC(get("year"), get("month") - 1, get("day"), get("hour"), get("minute"), get("second"));
  return wall - Math.floor(utcMs / 1000) * 1000;
}

/** A wall-clock time typed in the site's time zone ("2026-06-01T10:00") as a UTC instant. */
export function zonedWallTimeToUtc(wall: string, timeZone: string): Date {
  const match = /^(\d{4})-(\d{2})-(\d{2})T(\d{2}):(\d{2})(?::(\d{2}))?$/.exec(wall);
  if (!match) throw new Error(t("error.notDateTime", { value: wall }));
  const [y, mo, d, h, mi, s] = match.slice(1).map((v) => Number(v ?? 0));
  const asUtc = Date.UTC(y, mo - 1, d, h, mi, s);
  // Two passes find the offset in force at that wall time, also next to a DST change.
  let guess = asUtc - zoneOffsetMs(asUtc, timeZone);
  guess = asUtc - zoneOffsetMs(guess, timeZone);
  return new Date(guess);
}

/** The value for a datetime-local input showing `date` in the site's time zone. */
export function toZonedWallTime(date: Date, timeZone: string): string {
  const shifted = new Date(date.getTime() + zoneOffsetMs(date.getTime(), timeZone));
  return shifted.toISOString().slice(0, 16);
}

export function escapeHtml(text: string): string {
  return text.replace(/[&<>"']/g, (c) => `&#${c.charCodeAt(0)};`);
}

import { describe, expect, it } from "vitest";
import {
  escapeHtml,
  formatArea,
  formatBytes,
  formatDateTime,
  formatMetres,
  formatVolume,
  parseApiTime,
  toZonedWallTime,
  zonedWallTimeToUtc,
} from "./format";

describe("units", () => {
  it("says the unit of every number", () => {
    expect(formatMetres(-2.456)).toBe("-2.46 m");
    expect(formatArea(1234.4)).toBe("1,234 m²");
    expect(formatArea(12.34)).toBe("12.3 m²");
    expect(formatArea(250_000)).toBe("25 ha");
    expect(formatVolume(5678.9)).toBe("5,679 m³");
    expect(formatBytes(3_500_000_000)).toBe("3.5 GB");
    expect(formatMetres(null)).toBe("—");
  });
});

describe("times in the site's time zone", () => {
  it("shows an API time (UTC) in the site's zone", () => {
    expect(formatDateTime("2026-06-01T10:00:00Z", "Asia/Kathmandu")).toMatch(/1 Jun 2026, 15:45/);
    expect(formatDateTime("2026-06-01T10:00:00", "Europe/Rome")).toMatch(/1 Jun 2026, 12:00/);
  });

  it("reads naive SQLite times as UTC", () => {
    expect(parseApiTime("2026-06-01T10:00:00").toISOString()).toBe("2026-06-01T10:00:00.000Z");
    expect(parseApiTime("2026-06-01T10:00:00+02:00").toISOString()).toBe("2026-06-01T08:00:00.000Z");
  });

  it("turns a wall time typed in the site's zone into UTC, across DST", () => {
    expect(zonedWallTimeToUtc("2026-06-01T10:00", "Europe/Rome").toISOString()).toBe("2026-06-01T08:00:00.000Z");
    expect(zonedWallTimeToUtc("2026-01-15T10:00", "Europe/Rome").toISOString()).toBe("2026-01-15T09:00:00.000Z");
    expect(zonedWallTimeToUtc("2026-03-29T03:30", "Europe/Rome").toISOString()).toBe("2026-03-29T01:30:00.000Z");
    expect(zonedWallTimeToUtc("2026-06-01T10:00", "America/La_Paz").toISOString()).toBe("2026-06-01T14:00:00.000Z");
    expect(() => zonedWallTimeToUtc("June", "UTC")).toThrow(/not a date/);
  });

  it("round-trips through the datetime input's value", () => {
    const instant = new Date("2026-07-01T23:30:00Z");
    const wall = toZonedWallTime(instant, "Asia/Kathmandu");
    expect(wall).toBe("2026-07-02T05:15");
    expect(zonedWallTimeToUtc(wall, "Asia/Kathmandu").toISOString()).toBe(instant.toISOString());
  });
});

it("escapes text put into HTML", () => {
  expect(escapeHtml(`<img src=x onerror="a">`)).not.toContain("<");
});

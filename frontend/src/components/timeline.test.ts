import { expect, it } from "vitest";
import type { Survey } from "../types";
import { renderTimeline, timelinePositions } from "./timeline";

const survey = (id: number, captured_at: string): Survey => ({
  id, site_id: 1, name: `s${id}`, captured_at, kind: "dsm", status: "ready", crs: null, footprint: null,
  resolution_m: 0.5, source_file: null, warnings: [], quality: null, created_at: captured_at,
});

it("places surveys along the axis by capture time", () => {
  const surveys = [survey(1, "2026-06-01T00:00:00Z"), survey(2, "2026-06-11T00:00:00Z"), survey(3, "2026-07-01T00:00:00Z")];
  expect(timelinePositions(surveys).map((p) => p.toFixed(3))).toEqual(["0.000", "0.333", "1.000"]);
  expect(timelinePositions([surveys[0]])).toEqual([0.5]);
});

it("writes times in the site's zone with units", () => {
  const html = renderTimeline([survey(1, "2026-06-01T22:30:00Z")], "Asia/Tokyo");
  expect(html).toContain("2 Jun 2026, 07:30");
  expect(html).toContain("0.5 m pixels");
});

it("shows a survey's warnings in its row", () => {
  const warned = { ...survey(1, "2026-06-01T22:30:00Z"), warnings: ["flight.SRT: 1 of 6 blocks unreadable and skipped (line 11: …)"] };
  const html = renderTimeline([warned, survey(2, "2026-06-02T22:30:00Z")], "UTC");
  const box = document.createElement("div");
  box.innerHTML = html;
  const rows = box.querySelectorAll(".survey");
  expect(rows[0].querySelector(".survey-warnings summary")?.textContent).toContain("1 warning");
  expect(rows[0].textContent).toContain("line 11");
  expect(rows[1].querySelector(".survey-warnings")).toBeNull();
});

it("marks a survey that missed its quality bounds in its row, and no other", () => {
  const missed = "Only 62% of the area seen by two or more cameras has measured heights, below the 80% needed";
  const failed = {
    ...survey(1, "2026-06-01T22:30:00Z"),
    kind: "images" as const,
    quality: {
      passed: false,
      checks: [
        { name: "overlap_coverage" as const, value: 0.62, bound: 0.8, passed: false, message: missed },
        { name: "segments_dropped" as const, value: 0, bound: null, passed: true, message: "The flight's one segment was placed on the ground." },
      ],
    },
  };
  const passed = { ...survey(2, "2026-06-02T22:30:00Z"), quality: { passed: true, checks: [] } };
  const box = document.createElement("div");
  box.innerHTML = renderTimeline([failed, passed, survey(3, "2026-06-03T22:30:00Z")], "UTC");
  const rows = box.querySelectorAll(".survey");
  expect(rows[0].querySelector(".survey-quality summary")?.textContent).toBe(`Missed its quality bounds: ${missed}`);
  expect(rows[0].querySelectorAll(".survey-quality li")).toHaveLength(2);
  expect(rows[1].querySelector(".survey-quality")).toBeNull();
  expect(rows[2].querySelector(".survey-quality")).toBeNull();
});

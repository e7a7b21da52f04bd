import { expect, it } from "vitest";
import type { Survey } from "../types";
import { renderTimeline, timelinePositions } from "./timeline";

const survey = (id: number, captured_at: string): Survey => ({
  id, site_id: 1, name: `s${id}`, captured_at, kind: "dsm", status: "ready", crs: null, footprint: null,
  resolution_m: 0.5, source_file: null, created_at: captured_at,
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

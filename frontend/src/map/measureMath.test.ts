import { describe, expect, it } from "vitest";
import { pathLength, polygonArea, profileSvg } from "./measureMath";

describe("lengths and areas on the ground", () => {
  it("measures a degree of latitude and a path's segments", () => {
    expect(pathLength([[139, 36], [139, 37]])).toBeCloseTo(111195, -1);
    expect(pathLength([[0, 0], [0.001, 0], [0.001, 0.001]])).toBeCloseTo(2 * 111.195, 0);
    expect(pathLength([[5, 5]])).toBe(0);
  });
  it("measures a 100 m square at 36° N to the square metre", () => {
    const dLat = 100 / 111195.08;
    const dLon = dLat / Math.cos((36 * Math.PI) / 180);
    const square: [number, number][] = [[139, 36], [139 + dLon, 36], [139 + dLon, 36 + dLat], [139, 36 + dLat]];
    expect(polygonArea(square)).toBeCloseTo(10000, -1);
    expect(polygonArea(square.slice(0, 2))).toBe(0);
  });
});

describe("profileSvg", () => {
  it("draws one line per DSM, broken where it has no height", () => {
    const svg = profileSvg({ distance_m: [0, 5, 10], length_m: 10, heights_m: { pre: [10, null, 12], post: [10, 9, 8] } });
    expect(svg).toContain('aria-label="Elevation profile, 10.0 m"');
    const pre = svg.match(/<path d="([^"]*)"[^>]*><title>pre/)?.[1] ?? "";
    expect(pre.match(/M/g)?.length).toBe(2); // two pieces: the gap lifts the pen
    expect(svg).toContain("12.0 m");
    expect(svg).toContain("8.0 m");
  });
  it("says so when the line has no height at all", () => {
    expect(profileSvg({ distance_m: [0, 1], length_m: 1, heights_m: { dsm: [null, null] } })).toContain("No height");
  });
});

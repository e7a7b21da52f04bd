import { describe, expect, it } from "vitest";
import { formatLatLon, formatUtm, toUtm, utmZone } from "./utm";

describe("toUtm", () => {
  // Reference values from pyproj (EPSG:4326 -> EPSG:326xx / 327xx).
  it("matches PROJ in the northern hemisphere", () => {
    const utm = toUtm(36.0663, 139.1032);
    expect(utm.zone).toBe(54);
    expect(utm.easting).toBeCloseTo(329179.47, 1);
    expect(utm.northing).toBeCloseTo(3992967.12, 1);
  });
  it("matches PROJ south of the equator", () => {
    const utm = toUtm(-33.8688, 151.2093);
    expect(utm.zone).toBe(56);
    expect(utm.hemisphere).toBe("S");
    expect(utm.easting).toBeCloseTo(334368.63, 1);
    expect(utm.northing).toBeCloseTo(6250948.35, 1);
  });
  it("puts the central meridian at 500 km east", () => {
    expect(toUtm(10, 3).easting).toBeCloseTo(500000, 3);
    expect(utmZone(3)).toBe(31);
    expect(utmZone(180)).toBe(60);
  });
});

describe("formatting", () => {
  it("writes hemispheres, not signs", () => {
    expect(formatLatLon(-1.5, -70.25)).toBe("1.500000° S, 70.250000° W");
    expect(formatUtm({ zone: 54, hemisphere: "N", easting: 419350.24, northing: 3990820.66 })).toBe("54N 419350.2 E 3990820.7 N");
  });
});

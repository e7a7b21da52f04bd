import { describe, expect, it } from "vitest";
import { correctionText } from "./alignment";

describe("correctionText", () => {
  it("states the shift and the rotation", () => {
    expect(correctionText({ shift_m: { east: 2.1, north: 0.4, up: -7.5 }, rotation_deg: 0.021 })).toBe(
      "post moved 2.10 m E, 0.40 m N, −7.50 m up and turned 0.02° to match pre",
    );
  });
  it("leaves out a rotation too small to matter and never writes −0.00", () => {
    expect(correctionText({ shift_m: { east: -0.001, north: 0, up: 0.2 }, rotation_deg: 0.001 })).toBe(
      "post moved 0.00 m E, 0.00 m N, 0.20 m up to match pre",
    );
  });
  it("says nothing before the co-registration ran", () => {
    expect(correctionText(null)).toBeNull();
    expect(correctionText({})).toBeNull();
  });
});

import { describe, expect, it } from "vitest";
import { cssGradient, legendPosition, rescaleParam, symmetricRange, ticks, unionRange } from "./colormap";

describe("legends", () => {
  it("uses one stretch for pre and post", () => {
    expect(unionRange([[100, 140], [95, 130], null])).toEqual([95, 140]);
    expect(unionRange([null])).toBeNull();
  });

  it("centres Δh on zero with a round symmetric range", () => {
    expect(symmetricRange([-3.2, 1.1])).toEqual([-5, 5]);
    expect(symmetricRange([-0.4, 2.2])).toEqual([-2.5, 2.5]);
    expect(symmetricRange(null)).toEqual([-1, 1]);
    const [low, high] = symmetricRange([-3.2, 1.1]);
    expect(legendPosition(0, low, high)).toBe(0.5);
  });

  it("puts round ticks in the range", () => {
    expect(ticks(-5, 5)).toEqual([-5, -2.5, 0, 2.5, 5]);
    expect(ticks(1012.3, 1047.9)).toEqual([1020, 1030, 1040]);
  });

  it("writes the gradient and the rescale parameter", () => {
    expect(cssGradient("rdbu_r")).toMatch(/^linear-gradient\(to right, #053061/);
    expect(() => cssGradient("rainbow")).toThrow();
    expect(rescaleParam([-2.5, 2.5])).toBe("-2.500,2.500");
  });
});

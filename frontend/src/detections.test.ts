import { describe, expect, it } from "vitest";
import { detectionPopupHtml, detectionStyle, type HistoryEntry, historyHtml, scoreColor, withInterval } from "./detections";
import { formatArea, formatVolume } from "./format";
import type { DetectionProperties } from "./types";

const props: DetectionProperties = {
  comparison_id: 1,
  area_m2: 1234.5,
  volume_loss_m3: 2100,
  volume_gain_m3: 15.25,
  max_abs_dh_m: 4.321,
  score: 0.9,
  method: "cnn",
  model_version: "slidenet-default@1",
  feedback: { confirmed: 1, false_alarm: 0, latest: { verdict: "confirmed", author: "maria", at: "2026-07-02T08:00:00Z" } },
};

describe("detections", () => {
  it("are redder and more opaque the higher their score", () => {
    expect(scoreColor(0)).toBe("rgb(221, 214, 254)");
    expect(scoreColor(1)).toBe("rgb(76, 29, 149)");
    expect(detectionStyle(0.9).fillOpacity).toBeGreaterThan(detectionStyle(0.2).fillOpacity);
  });

  it("popup gives area, volumes, max |Δh|, method and model with units", () => {
    const html = detectionPopupHtml(7, props, "Europe/Rome");
    for (const text of ["1,235 m²", "2,100 m³", "15.3 m³", "4.32 m", "cnn", "slidenet-default@1", "confirmed landslide by maria, 2 Jul 2026, 10:00"]) {
      expect(html).toContain(text);
    }
  });

  it("popup gives the 95 % intervals and the LoD when the method has them", () => {
    const scored: DetectionProperties = {
      ...props,
      area_m2: 812,
      volume_loss_m3: 300,
      method: "scored",
      model_version: "scorer-default@1",
      uncertainty: {
        area_m2_ci95: [760, 870],
        volume_loss_m3_ci95: [250.4, 351],
        volume_gain_m3_ci95: [0, 40],
        lod_m: 0.123,
      },
    };
    const html = detectionPopupHtml(3, scored, "UTC");
    for (const text of ["812 m² (95 %: 760–870 m²)", "300 m³ (95 %: 250–351 m³)", "15.3 m³ (95 %: 0–40 m³)", "LoD (95 %)", "0.12 m", "scorer-default@1"]) {
      expect(html).toContain(text);
    }
    // cnn detections have no intervals: the values alone, no LoD row.
    const cnn = detectionPopupHtml(4, { ...props, uncertainty: null }, "UTC");
    expect(cnn).not.toContain("95 %");
    expect(cnn).toContain("1,235 m²");
  });

  it("says the unit of an interval once, twice when its ends differ", () => {
    expect(withInterval(812, [760, 870], formatArea)).toBe("812 m² (95 %: 760–870 m²)");
    expect(withInterval(99_000, [90_000, 120_000], formatArea)).toBe("99,000 m² (95 %: 90,000 m²–12 ha)");
    expect(withInterval(5, undefined, formatVolume)).toBe("5 m³");
  });

  it("says a detection without a model has none, and escapes text", () => {
    const html = detectionPopupHtml(1, { ...props, method: "<b>threshold</b>", model_version: null }, "UTC");
    expect(html).toContain("&#60;b&#62;threshold");
    const plain = detectionPopupHtml(1, { ...props, method: "threshold", model_version: null }, "UTC");
    expect(plain).toContain("none (the method runs no model)");
  });
});

describe("a detection's position", () => {
  it("gives latitude/longitude and UTM, and the text its copy button copies", () => {
    const props = { area_m2: 10, score: 0.9, method: "threshold", feedback: null } as unknown as DetectionProperties;
    const html = detectionPopupHtml(2, props, "UTC", [36.0663, 139.1032]);
    expect(html).toContain("Centre: 36.066300° N, 139.103200° E");
    expect(html).toContain("UTM 54N 329179.5 E 3992967.1 N");
    expect(html).toContain('data-position="36.066300° N, 139.103200° E (UTM 54N 329179.5 E 3992967.1 N)"');
    expect(detectionPopupHtml(2, props, "UTC")).not.toContain("Copy position");
  });
});

describe("a detection's history", () => {
  const entry = (id: number, post: string, area: number, self: boolean): HistoryEntry => ({
    comparison_id: id, detection_id: id * 10, label: 1, pre_captured_at: "2026-06-01T10:00:00Z", post_captured_at: post,
    area_m2: area, volume_loss_m3: area / 2, volume_gain_m3: 0, max_abs_dh_m: 2, score: 1, overlap: self ? 1 : 0.85, this: self,
  });
  it("lists the same ground in time order, this comparison marked", () => {
    const html = historyHtml([entry(1, "2026-07-01T10:00:00Z", 2000, true), entry(2, "2026-08-01T10:00:00Z", 2600, false)], "UTC");
    expect(html).toContain("1 Jul 2026 (this one)");
    expect(html).toContain("2,600 m²");
    expect(html).toContain("85 %");
    expect(html).toContain("2 · detection 1");
  });
  it("says when nothing else was found there", () => {
    expect(historyHtml([entry(1, "2026-07-01T10:00:00Z", 2000, true)], "UTC")).toContain("No other comparison");
  });
});

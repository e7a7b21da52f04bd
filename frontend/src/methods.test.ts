import { describe, expect, it } from "vitest";
import { useLocale } from "./i18n";
import { comparisonParameters, detectionText, methodOptionsHtml, methodSummary } from "./methods";
import type { DetectionMethod } from "./types";

const methods: DetectionMethod[] = [
  { name: "scored", summary: "Candidates scored by a calibrated model.", stages: ["align", "coregister", "difference", "score"], default: true },
  { name: "threshold", summary: "The LoD method.", stages: ["align", "coregister", "difference", "vectorize"], default: false },
  { name: "cnn", summary: "SlideNet, a neural network.", stages: ["align", "coregister", "difference", "detect"], default: false },
];

describe("methods", () => {
  it("fill the select in the API's order with the API's default selected", () => {
    const select = document.createElement("select");
    select.innerHTML = methodOptionsHtml(methods);
    expect([...select.options].map((o) => o.value)).toEqual(["scored", "threshold", "cnn"]);
    expect(select.value).toBe("scored");
    expect(select.options[0].textContent).toBe("scored (default)");
    select.innerHTML = methodOptionsHtml(methods.map((m) => ({ ...m, default: m.name === "threshold" })));
    expect(select.value).toBe("threshold");
  });

  it("ask for mown grass to be set aside only where the method can and the user chose it", () => {
    expect(comparisonParameters("threshold", true)).toEqual({ vectorize: { vegetation_cut: true } });
    expect(comparisonParameters("threshold", false)).toEqual({});
    expect(comparisonParameters("scored", true)).toEqual({});
    expect(comparisonParameters("", true)).toEqual({});
  });

  it("give the chosen method's one line", () => {
    expect(methodSummary(methods, "threshold")).toBe("The LoD method.");
    expect(methodSummary(methods, "magic")).toBe("");
  });

  it("give it in Japanese on a Japanese page, and the server's words for a method it does not know", () => {
    useLocale("ja-JP");
    expect(methodSummary(methods, "threshold")).toMatch(/^LoD 法：画素ごとの検出限界（LoD95/);
    expect(methodSummary(methods, "cnn")).toMatch(/^SlideNet：前時期・後時期の両 DSM/);
    const later = [...methods, { name: "lidar", summary: "Added on the server later.", stages: [], default: false }];
    expect(methodSummary(later, "lidar")).toBe("Added on the server later.");
    expect(methodSummary(later, "magic")).toBe("");
  });

  it("say the LoD and the model a comparison used", () => {
    const detection = {
      method: "scored", lod_m: 0.1234, lod_p10_m: 0.08, lod_p90_m: 0.2, error_model: "heteroscedastic", model: "scorer-default@1",
    };
    expect(detectionText(detection)).toBe("LoD 0.12 m (0.08–0.2 m, heteroscedastic) · model scorer-default@1");
    expect(detectionText({ ...detection, method: "threshold", model: null })).toBe("LoD 0.12 m (0.08–0.2 m, heteroscedastic)");
    expect(detectionText({ ...detection, lod_m: null, lod_p10_m: null, lod_p90_m: null, error_model: null, model: null })).toBe("");
    expect(detectionText(undefined)).toBe("");
  });
});

import { beforeEach, describe, expect, it } from "vitest";
import { useLocale } from "./i18n";
import type { QualityCheck, SurveyQuality } from "./types";
import {
  comparisonWarningsHtml,
  fileWarningText,
  fileWarningsHtml,
  qualitySummary,
  surveyQualityHtml,
  surveyWarningsHtml,
  warningCount,
} from "./warnings";

const skipped = "flight.SRT: 3 of 546 blocks unreadable and skipped (line 11: unreadable subtitle time range)";

it("names the file in every warning shown under it, once", () => {
  expect(fileWarningText("flight.SRT", skipped)).toBe(skipped);
  expect(fileWarningText("flight.SRT", "flight.SRT, line 4: no fix")).toBe("flight.SRT, line 4: no fix");
  expect(fileWarningText("flight.SRT", "the video's creation time is its end; offset adjusted")).toBe(
    "flight.SRT: the video's creation time is its end; offset adjusted",
  );
  expect(warningCount(1)).toBe("1 warning");
  expect(warningCount(2)).toBe("2 warnings");
});

it("puts a notice under each file read with warnings, and none under the others", () => {
  const html = fileWarningsHtml([
    { name: "DJI_0001.MP4", warnings: [] },
    { name: "flight.SRT", warnings: [skipped, "the clock times are <local>"] },
  ]);
  const box = document.createElement("div");
  box.innerHTML = html;
  const notices = box.querySelectorAll(".file-warnings");
  expect(notices).toHaveLength(1);
  expect(notices[0].getAttribute("data-file")).toBe("flight.SRT");
  expect(notices[0].textContent).toContain("flight.SRT was read with 2 warnings:");
  expect([...notices[0].querySelectorAll("li")].map((li) => li.textContent)).toEqual([
    skipped,
    "flight.SRT: the clock times are <local>",
  ]);
  expect(fileWarningsHtml([{ name: "a.SRT", warnings: [] }])).toBe("");
});

it("shows a survey's warnings behind their count", () => {
  expect(surveyWarningsHtml([])).toBe("");
  const box = document.createElement("div");
  box.innerHTML = surveyWarningsHtml([skipped]);
  expect(box.querySelector("summary")?.textContent).toBe("Read with 1 warning: what was skipped or assumed");
  expect(box.querySelector("li")?.textContent).toBe(skipped);
});

const check = (name: QualityCheck["name"], passed: boolean, message: string): QualityCheck => ({
  name,
  value: 1,
  bound: 1,
  passed,
  message,
});
const residual =
  "The survey may be distorted or its flight log wrong: the placed cameras are 7.20 m (horizontal RMS) from the logged GPS positions, more than the 5.0 m allowed for stand-alone GPS <about 1 m>.";
const outliers = "6 of 20 photos (30%) had GPS positions that disagree with the others and were left out";

it("sums up a missed verdict by its first failed check and how many more failed", () => {
  expect(qualitySummary(null)).toBeNull();
  expect(qualitySummary(undefined)).toBeNull();
  expect(qualitySummary({ passed: true, checks: [check("overlap_coverage", true, "92% measured")] })).toBeNull();
  const one: SurveyQuality = {
    passed: false,
    checks: [check("segments_dropped", true, "All 2 segments placed"), check("georeference_residual", false, residual)],
  };
  expect(qualitySummary(one)).toBe(`Missed its quality bounds: ${residual}`);
  const two: SurveyQuality = { passed: false, checks: [...one.checks, check("photo_outliers", false, outliers)] };
  expect(qualitySummary(two)).toBe(`Missed its quality bounds: ${residual} (and 1 more)`);
});

it("shows every check behind the mark, escaped, and nothing for a survey that passed", () => {
  expect(surveyQualityHtml(null)).toBe("");
  expect(surveyQualityHtml({ passed: true, checks: [check("overlap_coverage", true, "92% measured")] })).toBe("");
  const box = document.createElement("div");
  box.innerHTML = surveyQualityHtml({
    passed: false,
    checks: [check("segments_dropped", true, "All 2 segments placed"), check("georeference_residual", false, residual)],
  });
  expect(box.querySelector(".survey-quality summary")?.textContent).toBe(`Missed its quality bounds: ${residual}`);
  const items = [...box.querySelectorAll(".survey-quality li")];
  expect(items.map((li) => li.getAttribute("data-check"))).toEqual(["segments_dropped", "georeference_residual"]);
  expect(items.map((li) => li.className)).toEqual(["check-passed", "check-failed"]);
  expect(items[1].textContent?.trim()).toBe(`Missed: ${residual}`);
  expect(box.innerHTML).not.toContain("<about 1 m>");
});

it("keeps the server's own words for a check with a key on an English page", () => {
  const over: QualityCheck = {
    ...check("georeference_residual", false, residual),
    text: { key: "residual.over", figures: { segment: "", rms_h: "7.31", bound: "5.0" } },
  };
  expect(qualitySummary({ passed: false, checks: [over] })).toBe(`Missed its quality bounds: ${residual}`);
  const box = document.createElement("div");
  box.innerHTML = surveyWarningsHtml([residual], { passed: false, checks: [over] });
  expect(box.querySelector("li")?.textContent).toBe(residual);
});

it("lists a comparison's warnings about its surveys' quality", () => {
  expect(comparisonWarningsHtml([])).toBe("");
  expect(comparisonWarningsHtml(undefined)).toBe("");
  const warning = `The post-event survey "May flight" missed its quality bounds: ${outliers}`;
  const box = document.createElement("div");
  box.innerHTML = comparisonWarningsHtml([warning]);
  expect(box.querySelector("summary")?.textContent).toBe("Its surveys missed a quality bound: the changes are less sure");
  expect(box.querySelector("li")?.textContent).toBe(warning);
});

describe("on a Japanese page", () => {
  beforeEach(() => useLocale("ja-JP"));

  it("titles the server's warnings in Japanese and marks them as its English words", () => {
    const box = document.createElement("div");
    box.innerHTML = fileWarningsHtml([{ name: "flight.SRT", warnings: [skipped] }]);
    expect(box.querySelector("p")?.textContent).toBe("flight.SRT の読み込みで 1 件の警告がありました：");
    expect(box.querySelector(".server-original")?.textContent).toBe("各警告はサーバーが出力した原文（英語）です：");
    expect(box.querySelector("ul")?.getAttribute("lang")).toBe("en");
    expect(box.querySelector("li")?.textContent).toBe(skipped);
    box.innerHTML = surveyWarningsHtml([skipped]);
    expect(box.querySelector(".server-original")).not.toBeNull();
    expect(box.querySelector("li")?.textContent).toBe(skipped);
    box.innerHTML = comparisonWarningsHtml([outliers]);
    expect(box.querySelector(".server-original")).not.toBeNull();
  });

  it("names a missed check in Japanese, with the server's message behind it", () => {
    const quality: SurveyQuality = {
      passed: false,
      checks: [check("segments_dropped", true, "All 2 segments placed"), check("georeference_residual", false, residual)],
    };
    expect(qualitySummary(quality)).toBe("品質基準を満たしていません：復元したカメラ位置と GPS 記録の差");
    const box = document.createElement("div");
    box.innerHTML = surveyQualityHtml(quality);
    const missed = box.querySelectorAll(".survey-quality li")[1];
    expect(missed.textContent?.replace(/\s+/g, " ").trim()).toBe(`未達： 復元したカメラ位置と GPS 記録の差：${residual}`);
    expect(missed.querySelector("span[lang=en]")?.textContent).toBe(residual);
  });

  it("words a check in Japanese from its key and figures, and drops the English copy from the warnings", () => {
    const over: QualityCheck = {
      ...check("georeference_residual", false, residual),
      text: { key: "residual.over", figures: { segment: "2", rms_h: "7.31", bound: "5.0" } },
    };
    const dropped: QualityCheck = {
      ...check("segments_dropped", true, "1 of 3 flight segments could not be placed"),
      text: { key: "segments.dropped", figures: { dropped: "1", total: "3", kept: "2" } },
    };
    const quality: SurveyQuality = { passed: false, checks: [dropped, over] };
    const japanese = "調査がゆがんでいるか、フライトログが誤っている可能性があります：配置したカメラは記録された GPS 位置から 7.31 m（水平 RMS）（区間 2）離れており、単独測位 GPS に許される 5.0 m（1 回の飛行中のずれは約 1 m）を超えています。";
    expect(qualitySummary(quality)).toBe(`品質基準を満たしていません：${japanese}`);
    const box = document.createElement("div");
    box.innerHTML = surveyQualityHtml(quality);
    const items = box.querySelectorAll(".survey-quality li");
    expect(items[0].textContent).toContain("飛行 3 区間のうち 1 区間を地上に配置できず除外しました。");
    expect(items[1].textContent).toContain(japanese);
    expect(box.innerHTML).not.toContain("span lang=\"en\"");
    box.innerHTML = surveyWarningsHtml([residual, skipped], quality);
    expect([...box.querySelectorAll("li")].map((li) => li.textContent)).toEqual([skipped]);
  });

  it("shows the server's message for a check it does not know", () => {
    const later = { ...check("segments_dropped", false, "A check added later"), name: "sharpness" as QualityCheck["name"] };
    expect(qualitySummary({ passed: false, checks: [later] })).toBe("品質基準を満たしていません：A check added later");
  });
});

import { afterEach, describe, expect, it } from "vitest";
import { formatArea, formatDate, formatDateTime, formatFixed, formatMetres, formatPercent, formatVolume } from "../format";
import { correctionText } from "../map/alignment";
import { differenceLegend, elevationLegend } from "../map/legend";
import { profileSvg } from "../map/measureMath";
import type { Message } from "./catalogue";
import { catalogues, chooseLanguage, currentLanguage, currentLocale, languages, onLanguageChange, resolveLocale, t, useLocale } from "./index";

const english = catalogues().find((c) => c.code === "en")!;
const forms = (m: Message) => (typeof m === "string" ? [m] : Object.values(m));
const params = (m: Message) => new Set(forms(m).flatMap((f) => [...(f as string).matchAll(/\{(\w+)\}/g)].map((x) => x[1])));

afterEach(() => localStorage.removeItem("slidewatch.language"));

describe("the catalogues", () => {
  it("has English and Japanese, each by its own name", () => {
    expect(languages()).toEqual([
      { code: "en", name: "English" },
      { code: "ja", name: "日本語" },
    ]);
  });

  for (const catalogue of catalogues()) {
    it(`${catalogue.code} has every key of English and no other, with the same parameters`, () => {
      expect(Object.keys(catalogue.messages).sort()).toEqual(Object.keys(english.messages).sort());
      for (const [key, message] of Object.entries(english.messages)) {
        const theirs = catalogue.messages[key as keyof typeof english.messages];
        expect([key, [...params(theirs)].sort()]).toEqual([key, [...params(message)].sort()]);
      }
    });

    it(`${catalogue.code} gives each plural message "other" and only its language's categories`, () => {
      const categories = new Intl.PluralRules(catalogue.locale).resolvedOptions().pluralCategories as string[];
      for (const [key, message] of Object.entries(catalogue.messages)) {
        if (typeof message === "string") continue;
        expect([key, "other" in message]).toEqual([key, true]);
        for (const category of Object.keys(message)) expect([key, categories.includes(category)]).toEqual([key, true]);
      }
    });
  }

  it("translates Japanese: no message is the English one, but for units and names kept as they are", () => {
    const japanese = catalogues().find((c) => c.code === "ja")!;
    const same = Object.entries(english.messages)
      .filter(([key, message]) => JSON.stringify(japanese.messages[key as keyof typeof english.messages]) === JSON.stringify(message))
      .map(([key]) => key);
    expect(same.sort()).toEqual(
      [
        "account.kindApi",
        "map.dsm",
        "map.heightDsm",
        "methods.lod",
        "survey.kindDsm",
        "unit.bytes",
        "unit.cubicMetres",
        "unit.hectares",
        "unit.metres",
        "unit.squareMetres",
        "upload.kindDsm",
      ].sort(),
    );
  });
});

describe("choosing the language", () => {
  it("takes the browser's first language the page has, with its region for formats", () => {
    expect(resolveLocale(["ja-JP", "en-US"], null)).toBe("ja-JP");
    expect(resolveLocale(["ja"], null)).toBe("ja-JP");
    expect(resolveLocale(["en-US", "ja"], null)).toBe("en-US");
    expect(resolveLocale(["fr-FR", "ja"], null)).toBe("ja-JP");
    expect(resolveLocale(["fr-FR", "de"], null)).toBe("en-GB");
    expect(resolveLocale([], null)).toBe("en-GB");
  });

  it("prefers the user's choice over the browser's languages", () => {
    expect(resolveLocale(["en-GB"], "ja")).toBe("ja-JP");
    expect(resolveLocale(["ja-JP", "en-US"], "en")).toBe("en-US");
    expect(resolveLocale(["ja-JP"], "tlh")).toBe("ja-JP"); // a language without a file: ignored
  });

  it("keeps the choice, marks <html lang> and tells the page to draw itself again", () => {
    let redrawn = 0;
    onLanguageChange(() => (redrawn += 1));
    chooseLanguage("ja");
    expect(localStorage.getItem("slidewatch.language")).toBe("ja");
    expect(currentLanguage()).toBe("ja");
    expect(document.documentElement.lang).toBe("ja");
    expect(t("header.signOut")).toBe("ログアウト");
    chooseLanguage("en");
    expect(currentLanguage()).toBe("en");
    expect(document.documentElement.lang).toBe("en");
    expect(redrawn).toBe(2);
  });
});

describe("messages", () => {
  it("fills in parameters and picks the plural form", () => {
    expect(t("count.detections", { count: 1 })).toBe("1 detection");
    expect(t("count.detections", { count: 0 })).toBe("0 detections");
    expect(t("count.detections", { count: 12 })).toBe("12 detections");
    expect(t("warnings.comparisonMissed", { count: 1 })).toBe("Its surveys missed a quality bound: the changes are less sure");
    expect(t("warnings.comparisonMissed", { count: 3 })).toBe("Its surveys missed 3 quality bounds: the changes are less sure");
    expect(t("site.showComparison", { id: 1234 })).toBe("Show comparison 1234 on the map"); // an id: no separator
    useLocale("ja-JP");
    expect(t("count.detections", { count: 1 })).toBe("1 件の検出");
    expect(t("count.detections", { count: 12 })).toBe("12 件の検出");
    expect(t("site.showComparison", { id: 7 })).toBe("比較 7 を地図に表示");
  });
});

describe("formats of the locale", () => {
  it("writes dates and times in British English, in the site's time zone", () => {
    expect(currentLocale()).toBe("en-GB");
    expect(formatDateTime("2026-06-01T10:00:00Z", "Asia/Tokyo")).toBe("1 Jun 2026, 19:00 GMT+9");
    expect(formatDate("2026-06-01T20:00:00Z", "Asia/Tokyo")).toBe("2 Jun 2026");
  });

  it("writes them the Japanese way in Japanese, still in the site's time zone", () => {
    useLocale("ja-JP");
    expect(formatDateTime("2026-06-01T10:00:00Z", "Asia/Tokyo")).toBe("2026年6月1日 19:00 JST");
    expect(formatDateTime("2026-06-01T10:00:00Z", "Europe/Rome")).toBe("2026年6月1日 12:00 GMT+2");
    expect(formatDate("2026-06-01T20:00:00Z", "Asia/Tokyo")).toBe("2026年6月2日");
  });

  it("writes them the American way for a browser in en-US", () => {
    useLocale("en-US");
    expect(formatDate("2026-06-01T20:00:00Z", "Asia/Tokyo")).toBe("Jun 2, 2026");
  });

  it("writes numbers with the locale's separators and the units' symbols", () => {
    expect(formatArea(1234.4)).toBe("1,234 m²");
    expect(formatMetres(0.125, 2)).toBe("0.13 m");
    expect(formatPercent(0.456)).toBe("45 %");
    expect(formatFixed(0.5, 2)).toBe("0.50");
    useLocale("ja-JP");
    expect(formatArea(1234.4)).toBe("1,234 m²");
    expect(formatArea(250_000)).toBe("25 ha");
    expect(formatVolume(5678.9)).toBe("5,679 m³");
    expect(formatPercent(0.456)).toBe("45%");
    expect(formatFixed(0.5, 2)).toBe("0.50");
  });
});

describe("the map in Japanese", () => {
  it("states the co-registration, the legends and the profile in Japanese, with their numbers", () => {
    useLocale("ja-JP");
    expect(correctionText({ shift_m: { east: 2.1, north: -0.4, up: 0.2 }, rotation_deg: 0.021 })).toBe(
      "前時期に合わせて後時期を東へ 2.10 m、北へ −0.40 m、上へ 0.20 m 移動、0.02° 回転",
    );
    const elevation = elevationLegend([100, 140], t("map.preDsm"), "elevation-pre");
    expect(elevation.dataset.legend).toBe("elevation-pre"); // the same legend whatever its words
    expect(elevation.querySelector("figcaption")?.textContent).toBe("前時期 DSM：標高（m、その DSM の基準面から）");
    expect(differenceLegend([-2, 2]).querySelector("figcaption")?.textContent).toBe("Δh = 後時期 − 前時期（m）：青は減少、赤は増加");
    const svg = profileSvg({ distance_m: [0, 1234.5], length_m: 1234.5, heights_m: { dsm: [10, 12] } });
    expect(svg).toContain('aria-label="標高断面、1,234.5 m"');
  });
});

import { describe, expect, it } from "vitest";
import { detectionPopupHtml } from "../detections";
import { deliveryTarget } from "./alerts";
import { detectionsUrl, productName } from "./downloads";
import { reportLine } from "./reports";
import { cronOf } from "./schedules";
import { t } from "../i18n";
import { timeZones } from "./tools";

describe("the site's tools", () => {
  it("says one thing in the singular and more in the plural", () => {
    expect(t("count.detections", { count: 1 })).toBe("1 detection");
    expect(t("count.detections", { count: 0 })).toBe("0 detections");
    expect(t("count.detections", { count: 5 })).toBe("5 detections");
  });

  it("builds cron expressions from plain choices", () => {
    const base = { minute: 15, hour: 6, weekday: 1, monthday: 3 };
    expect(cronOf({ ...base, frequency: "hourly" })).toBe("15 * * * *");
    expect(cronOf({ ...base, frequency: "daily" })).toBe("15 6 * * *");
    expect(cronOf({ ...base, frequency: "weekly" })).toBe("15 6 * * 1");
    expect(cronOf({ ...base, frequency: "monthly" })).toBe("15 6 3 * *");
    expect(cronOf({ ...base, frequency: "custom" })).toBeNull();
  });

  it("lists the IANA time zones, UTC among them", () => {
    const zones = timeZones();
    expect(zones).toContain("UTC");
    expect(zones).toContain("Asia/Tokyo");
  });

  it("links each detection format to the API", () => {
    expect(detectionsUrl(3, 7, "geojson")).toBe("/api/v1/sites/3/comparisons/7/detections");
    expect(detectionsUrl(3, 7, "gpkg")).toBe("/api/v1/sites/3/comparisons/7/detections/gpkg");
    expect(productName("dh")).toContain("Δh");
    expect(productName("some_new_kind")).toBe("some new kind");
  });

  it("words a report in the site's time zone, with its detections counted", () => {
    const line = reportLine(
      {
        id: 4,
        comparison_id: 2,
        schedule_id: null,
        trigger: "on_demand",
        status: "succeeded",
        summary: { detections: 1 },
        error: null,
        created_at: "2026-06-01T10:00:00Z",
        finished_at: null,
        pdf_url: "/x.pdf",
        html_url: null,
      },
      "Asia/Tokyo",
    );
    expect(line).toContain("1 detection");
    expect(line).not.toContain("1 detections");
    expect(line).toContain("19:00");
  });

  it("names where a delivery went", () => {
    const d = { id: 1, channel: "webhook", webhook_id: 2, recipients: null, event: "test", status: "delivered", attempts: 1, delivered_at: null, last_error: null, created_at: "" };
    expect(deliveryTarget(d, [{ id: 2, url: "https://h.example/x", events: [], description: "", active: true }])).toBe("webhook https://h.example/x");
    expect(deliveryTarget({ ...d, channel: "email", recipients: ["a@b.example"] }, [])).toBe("e-mail to a@b.example");
  });

  it("names a detection by its label in the popup, not by its database id", () => {
    const props = {
      comparison_id: 9,
      label: 2,
      area_m2: 120,
      volume_loss_m3: 30,
      volume_gain_m3: 1,
      max_abs_dh_m: 1.5,
      score: 0.9,
      method: "threshold",
      model_version: null,
      feedback: { confirmed: 0, false_alarm: 0, latest: null },
    };
    const html = detectionPopupHtml(329, props, "UTC");
    expect(html).toContain("<h3>Detection 2</h3>");
    expect(html).not.toContain("Detection 329");
  });
});

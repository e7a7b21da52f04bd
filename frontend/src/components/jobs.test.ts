import { afterEach, expect, it, vi } from "vitest";
import type { Job } from "../types";
import { useLocale } from "../i18n";
import { JobsPanel, jobTitle } from "./jobs";

const failed: Job = {
  id: 7, site_id: 1, kind: "comparison", comparison_id: 3, survey_id: null, state: "failed", progress: 0.5,
  error: "coregister: the DSMs share no stable terrain", created_at: "2026-06-01T10:00:00Z", started_at: null,
  finished_at: "2026-06-01T10:05:00Z",
  stages: [
    { stage: "align", help: "both DSMs onto one grid", state: "succeeded", progress: 1, attempts: 1, started_at: null, finished_at: null, error: null, result: null, log: ["10:00:01 INFO attempt 1 started", "10:00:09 INFO succeeded in 8.0 s"] },
    { stage: "coregister", help: "post DSM shifted onto pre", state: "failed", progress: 0.3, attempts: 2, started_at: null, finished_at: null, error: "no stable terrain", result: null, log: ["10:00:10 INFO attempt 1 started", "10:00:30 ERROR failed: no stable terrain"] },
  ],
};

afterEach(() => vi.unstubAllGlobals());

it("shows a failed job's reason and retries it", async () => {
  const requests: Array<[string, string]> = [];
  vi.stubGlobal("fetch", async (url: string, init: RequestInit = {}) => {
    requests.push([init.method ?? "GET", url]);
    if (url.endsWith("/retry")) return new Response(JSON.stringify({ ...failed, state: "queued", error: null }), { status: 202 });
    return new Response("", { status: 200, headers: { "content-type": "text/event-stream" } });
  });
  const box = document.createElement("div");
  const panel = new JobsPanel(box, 1, "Europe/Rome", () => {});
  panel.show([failed]);
  expect(box.textContent).toContain("Failed: coregister: the DSMs share no stable terrain");
  expect(box.textContent).toContain("attempt 2");
  expect(box.textContent).toContain("post DSM shifted onto pre"); // the stage help the API sends
  expect(box.textContent).toContain("1 Jun 2026, 12:00");
  const retry = box.querySelector("button[data-retry]") as HTMLButtonElement;
  expect(retry.textContent).toBe("Retry job 7");
  retry.click();
  await vi.waitFor(() => expect(box.querySelector(".job-queued")).not.toBeNull());
  expect(requests[0]).toEqual(["POST", "/api/v1/sites/1/jobs/7/retry"]);
  expect(box.textContent).not.toContain("Failed:");
  panel.close();
});

it("keeps the history of every job with each stage's log", () => {
  vi.stubGlobal("fetch", async () => new Response("", { status: 200, headers: { "content-type": "text/event-stream" } }));
  const box = document.createElement("div");
  const panel = new JobsPanel(box, 1, "UTC", () => {});
  const older = Array.from({ length: 10 }, (_, i) => ({ ...failed, id: i + 1, state: "succeeded" as const, error: null }));
  panel.show([...older, { ...failed, id: 20 }]);
  expect(box.querySelectorAll("article.job")).toHaveLength(8);
  (box.querySelector("button[data-all-jobs]") as HTMLButtonElement).click();
  expect(box.querySelectorAll("article.job")).toHaveLength(11);
  const log = box.querySelector('[data-job="20"] details.job-log') as HTMLDetailsElement;
  expect(log.querySelector("summary")?.textContent).toBe("Stage logs of job 20");
  expect(log.textContent).toContain("coregister");
  expect(log.textContent).toContain("10:00:30 ERROR failed: no stable terrain");
  panel.close();
});

it("names the stages and says what they do in Japanese, the server's words for a stage it does not know", () => {
  vi.stubGlobal("fetch", async () => new Response("", { status: 200, headers: { "content-type": "text/event-stream" } }));
  useLocale("ja-JP");
  const box = document.createElement("div");
  const panel = new JobsPanel(box, 1, "Asia/Tokyo", () => {});
  const later = { ...failed.stages[0], stage: "resample", help: "a stage added on the server later", log: [] };
  panel.show([{ ...failed, stages: [...failed.stages, later] }]);
  const names = [...box.querySelectorAll(".stage-name")].map((s) => s.textContent);
  expect(names).toEqual(["グリッド統一", "位置合わせ（コレジストレーション）", "resample"]);
  const helps = [...box.querySelectorAll(".stage .muted")].map((s) => s.textContent);
  expect(helps).toEqual(["両 DSM を同じグリッドに揃える", "後時期 DSM を前時期 DSM に合わせて移動", "a stage added on the server later"]);
  expect(box.querySelector("progress")?.getAttribute("aria-label")).toBe("グリッド統一 の進捗");
  expect(box.textContent).toContain("失敗：（英語の原文）coregister: the DSMs share no stable terrain");
  const log = box.querySelector("details.job-log") as HTMLDetailsElement;
  expect([...log.querySelectorAll("h4")].map((h) => h.textContent)).toEqual(["グリッド統一", "位置合わせ（コレジストレーション）"]);
  expect(log.textContent).toContain("ワーカーが出力したログの原文（英語）です。");
  expect(jobTitle({ ...failed, kind: "report" })).toBe("ジョブ：報告書作成");
  expect(jobTitle({ ...failed, kind: "export" })).toBe("ジョブ：export");
  panel.close();
});

it("shows the stages as the server names them on an English page", () => {
  vi.stubGlobal("fetch", async () => new Response("", { status: 200, headers: { "content-type": "text/event-stream" } }));
  const box = document.createElement("div");
  const panel = new JobsPanel(box, 1, "UTC", () => {});
  panel.show([failed]);
  expect([...box.querySelectorAll(".stage-name")].map((s) => s.textContent)).toEqual(["align", "coregister"]);
  expect(box.querySelector(".stage .muted")?.textContent).toBe("both DSMs onto one grid");
  expect(box.textContent).not.toContain("in English");
  expect(jobTitle({ ...failed, kind: "report" })).toBe("report job");
  panel.close();
});

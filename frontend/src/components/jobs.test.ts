import { afterEach, expect, it, vi } from "vitest";
import type { Job } from "../types";
import { JobsPanel } from "./jobs";

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

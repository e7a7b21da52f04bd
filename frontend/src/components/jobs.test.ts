import { afterEach, expect, it, vi } from "vitest";
import type { Job } from "../types";
import { JobsPanel } from "./jobs";

const failed: Job = {
  id: 7, site_id: 1, kind: "comparison", comparison_id: 3, survey_id: null, state: "failed", progress: 0.5,
  error: "coregister: the DSMs share no stable terrain", created_at: "2026-06-01T10:00:00Z", started_at: null,
  finished_at: "2026-06-01T10:05:00Z",
  stages: [
    { stage: "align", help: "both DSMs onto one grid", state: "succeeded", progress: 1, attempts: 1, started_at: null, finished_at: null, error: null, result: null },
    { stage: "coregister", help: "post DSM shifted onto pre", state: "failed", progress: 0.3, attempts: 2, started_at: null, finished_at: null, error: "no stable terrain", result: null },
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

import { describe, expect, it } from "vitest";
import { SseParser } from "./sse";

describe("SseParser", () => {
  it("parses events split anywhere across chunks", () => {
    const stream = 'retry: 2000\n\nid: 1\nevent: job\ndata: {"state":"running"}\n\n: still working\n\nid: 2\nevent: job\ndata: {"state":"succeeded"}\n\n';
    for (const size of [1, 3, 7, stream.length]) {
      const parser = new SseParser();
      const events = [];
      for (let i = 0; i < stream.length; i += size) events.push(...parser.push(stream.slice(i, i + size)));
      expect(events.map((e) => [e.event, JSON.parse(e.data).state, e.id])).toEqual([
        ["job", "running", "1"],
        ["job", "succeeded", "2"],
      ]);
      expect(parser.retryMs).toBe(2000);
    }
  });

  it("joins multi-line data, takes CRLF and defaults the event name", () => {
    const parser = new SseParser();
    expect(parser.push("data: a\r\ndata: b\r\n\r\n")).toEqual([{ event: "message", data: "a\nb", id: undefined }]);
  });

  it("waits for the blank line that ends an event", () => {
    const parser = new SseParser();
    expect(parser.push("event: job\ndata: {}\n")).toEqual([]);
    expect(parser.push("\n")).toHaveLength(1);
  });
});

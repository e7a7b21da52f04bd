// Server-Sent Events over fetch, so that the Authorization header goes with the request
// (EventSource cannot send one, and a token in the URL ends up in access logs).

import { t } from "./i18n";

export interface SseEvent {
  event: string;
  data: string;
  id?: string;
}

/** Incremental parser of a text/event-stream (WHATWG HTML, "Parsing an event stream"). */
export class SseParser {
  private buffer = "";
  private data: string[] = [];
  private event = "";
  private id: string | undefined;
  retryMs: number | undefined;

  /** Feed decoded text; returns the events completed by it. */
  push(text: string): SseEvent[] {
    this.buffer += text;
    const events: SseEvent[] = [];
    let newline: number;
    while ((newline = this.buffer.search(/\r\n|\r|\n/)) >= 0) {
      const line = this.buffer.slice(0, newline);
      const width = this.buffer.startsWith("\r\n", newline) ? 2 : 1;
      this.buffer = this.buffer.slice(newline + width);
      const event = this.line(line);
      if (event) events.push(event);
    }
    return events;
  }

  private line(line: string): SseEvent | null {
    if (line === "") {
      if (!this.data.length) {
        this.event = "";
        return null;
      }
      const event = { event: this.event || "message", data: this.data.join("\n"), id: this.id };
      this.data = [];
      this.event = "";
      return event;
    }
    if (line.startsWith(":")) return null; // a comment: keep-alive
    const colon = line.indexOf(":");
    const field = colon < 0 ? line : line.slice(0, colon);
    let value = colon < 0 ? "" : line.slice(colon + 1);
    if (value.startsWith(" ")) value = value.slice(1);
    if (field === "data") this.data.push(value);
    else if (field === "event") this.event = value;
    else if (field === "id") this.id = value;
    else if (field === "retry" && /^\d+$/.test(value)) this.retryMs = Number(value);
    return null;
  }
}

export interface StreamOptions {
  headers: Record<string, string>;
  onEvent: (event: SseEvent) => void;
  /** Called when the server ends the stream (e.g. the job finished). */
  onEnd?: () => void;
  /** Called when the connection broke and will be tried again. */
  onRetry?: (error: unknown) => void;
  signal: AbortSignal;
}

/** Read an event stream, reconnecting after a dropped connection until the server ends it. */
export async function streamEvents(url: string, options: StreamOptions): Promise<void> {
  let retryMs = 2000;
  while (!options.signal.aborted) {
    const parser = new SseParser();
    try {
      const response = await fetch(url, {
        headers: { Accept: "text/event-stream", ...options.headers },
        signal: options.signal,
        cache: "no-store",
      });
      if (!response.ok || !response.body) throw new HttpStatusError(response.status);
      const reader = response.body.pipeThrough(new TextDecoderStream()).getReader();
      for (;;) {
        const { value, done } = await reader.read();
        if (done) break;
        for (const event of parser.push(value)) options.onEvent(event);
      }
      retryMs = parser.retryMs ?? retryMs;
      options.onEnd?.();
      return;
    } catch (error) {
      if (options.signal.aborted) return;
      if (error instanceof HttpStatusError && error.status >= 400 && error.status < 500) throw error;
      options.onRetry?.(error);
      retryMs = parser.retryMs ?? retryMs;
      await new Promise((resolve) => setTimeout(resolve, retryMs));
    }
  }
}

export class HttpStatusError extends Error {
  constructor(readonly status: number) {
    super(t("error.serverAnswered", { status }));
  }
}

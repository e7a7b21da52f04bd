// Resumable uploads with tus-js-client against our tus server (/api/v1/uploads).
// The file's SHA-256 goes with the metadata and is checked by the server on completion;
// tus-js-client remembers each upload's URL (localStorage), so an upload resumes after a
// dropped connection (it retries) and after a page reload (the same file chosen again).
// What is sent may be a rearranged form of the file (a video with its index first, see
// faststart.ts): the digest is of what is sent, the fingerprint of the file chosen.

import { sha256 } from "@noble/hashes/sha2";
import { bytesToHex } from "@noble/hashes/utils";
import * as tus from "tus-js-client";
import { authHeaders, errorMessage } from "./api";

const HASH_SLICE = 4 * 1024 * 1024;
export const RETRY_DELAYS_MS = [0, 1000, 3000, 5000, 10000, 20000];

export interface UploadCallbacks {
  onHashing?: (fraction: number) => void;
  /** The server knows the upload (its first request is answered). */
  onCreated?: () => void;
  onResuming?: (offset: number, total: number) => void;
  onProgress: (sent: number, total: number) => void;
  onRetry?: (message: string) => void;
  onSuccess: (uploadUrl: string) => void;
  onError: (message: string) => void;
}

function fingerprintOf(file: File): string {
  return ["slidewatch", file.name, file.type, file.size, file.lastModified].join("-");
}

/** SHA-256 of what is sent for `file` (the file, or `body` made from it), read in slices
 * (large files never sit whole in memory); remembered per file so that a resumed upload
 * does not read it all again. */
export async function fileSha256(
  file: File,
  onProgress?: (fraction: number) => void,
  body: Blob = file,
): Promise<string> {
  const key = `slidewatch.sha256.${fingerprintOf(file)}${body === file ? "" : ".rearranged"}`;
  const known = localStorage.getItem(key);
  if (known) return known;
  const hash = sha256.create();
  for (let offset = 0; offset < body.size; offset += HASH_SLICE) {
    const slice = await body.slice(offset, offset + HASH_SLICE).arrayBuffer();
    hash.update(new Uint8Array(slice));
    onProgress?.(Math.min(1, (offset + slice.byteLength) / body.size));
  }
  const hex = bytesToHex(hash.digest());
  localStorage.setItem(key, hex);
  return hex;
}

export function reasonOf(error: Error): string {
  const response = (error as tus.DetailedError).originalResponse;
  if (response) {
    const status = response.getStatus();
    let body: unknown = null;
    try {
      body = JSON.parse(response.getBody());
    } catch {
      /* not JSON */
    }
    return errorMessage(body, status);
  }
  return navigator.onLine === false ? "the connection is down" : error.message.split(", originalRequest")[0];
}

export interface RunningUpload {
  pause(): Promise<void>;
  resume(): void;
  cancel(): Promise<void>;
}

/** Hash, then upload `file` (or `body`, what is sent for it) with `metadata` (string
 * values); resumes a previous upload of the same file when there is one. */
export async function startUpload(
  file: File,
  metadata: Record<string, string>,
  chunkSize: number,
  callbacks: UploadCallbacks,
  body: Blob = file,
): Promise<RunningUpload> {
  const digest = await fileSha256(file, callbacks.onHashing, body);
  const upload = new tus.Upload(body, {
    endpoint: "/api/v1/uploads",
    chunkSize,
    retryDelays: RETRY_DELAYS_MS,
    metadata: { ...metadata, filename: file.name, sha256: digest },
    fingerprint: async () => fingerprintOf(file),
    storeFingerprintForResuming: true,
    removeFingerprintOnSuccess: true,
    onBeforeRequest: (request) => {
      for (const [name, value] of Object.entries(authHeaders())) request.setHeader(name, value);
    },
    onUploadUrlAvailable: () => callbacks.onCreated?.(),
    onProgress: (sent, total) => callbacks.onProgress(sent, total),
    onShouldRetry: (error, attempt) => {
      const status = (error as tus.DetailedError).originalResponse?.getStatus() ?? 0;
      const retry = status === 0 || status >= 500 || status === 409 || status === 423;
      if (retry) callbacks.onRetry?.(`Connection lost (${reasonOf(error)}); trying again (attempt ${attempt + 1})…`);
      return retry;
    },
    onSuccess: () => callbacks.onSuccess(upload.url ?? ""),
    onError: (error) => callbacks.onError(reasonOf(error)),
  });
  const previous = await upload.findPreviousUploads();
  if (previous.length) {
    upload.resumeFromPreviousUpload(previous[0]);
    const url = previous[0].uploadUrl;
    if (url) {
      const head = await fetch(url, { method: "HEAD", headers: { ...authHeaders(), "Tus-Resumable": "1.0.0" } });
      if (head.ok) callbacks.onResuming?.(Number(head.headers.get("Upload-Offset") ?? 0), file.size);
    }
  }
  upload.start();
  return {
    pause: () => upload.abort(false),
    resume: () => upload.start(),
    cancel: () => upload.abort(true),
  };
}

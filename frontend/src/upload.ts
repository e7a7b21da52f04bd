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
import { t } from "./i18n";

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
  return navigator.onLine === false ? t("upload.connectionDown") : error.message.split(", originalRequest")[0];
}

const TUS_HEADERS = { "Tus-Resumable": "1.0.0" };

/** The tus `Upload-Metadata` header: `key base64(value)` pairs, values as UTF-8. */
export function encodeMetadata(values: Record<string, string>): string {
  const base64 = (text: string) => btoa(String.fromCharCode(...new TextEncoder().encode(text)));
  return Object.entries(values)
    .map(([key, value]) => `${key} ${base64(value)}`)
    .join(",");
}

function createdKey(file: File, metadata: Record<string, string>): string {
  return `slidewatch.upload.${fingerprintOf(file)}.${metadata.survey_id ?? "dsm"}.${metadata.role ?? ""}`;
}

/** Make the server's upload of `file` (sending `body`) before any byte goes, or find the
 * one made before for it (a reload, a second try); its URL. A survey's files are all
 * created first, so that processing is asked for only once the server knows each one. */
export async function createUpload(
  file: File,
  metadata: Record<string, string>,
  body: Blob = file,
  onHashing?: (fraction: number) => void,
): Promise<string> {
  const key = createdKey(file, metadata);
  const known = localStorage.getItem(key);
  if (known) {
    const head = await fetch(known, { method: "HEAD", headers: { ...authHeaders(), ...TUS_HEADERS } }).catch(() => null);
    if (head?.ok) return known;
    localStorage.removeItem(key);
  }
  const digest = await fileSha256(file, onHashing, body);
  const headers = {
    ...authHeaders(),
    ...TUS_HEADERS,
    "Upload-Length": String(body.size),
    "Upload-Metadata": encodeMetadata({ ...metadata, filename: file.name, sha256: digest }),
  };
  // A slow or flaky connection may lose the request: tried again, as tus retries PATCHes.
  for (let attempt = 0; ; attempt++) {
    const response = await fetch("/api/v1/uploads", { method: "POST", headers }).catch(() => null);
    if (response?.status === 201) {
      const url = response.headers.get("Location") ?? "";
      localStorage.setItem(key, url);
      return url;
    }
    if (response && response.status < 500) {
      const reason = errorMessage(await response.json().catch(() => null), response.status);
      throw new Error(t("upload.notAccepted", { file: file.name, reason }));
    }
    if (attempt >= RETRY_DELAYS_MS.length - 1) throw new Error(t("upload.unreachable", { file: file.name }));
    await new Promise((r) => setTimeout(r, RETRY_DELAYS_MS[attempt + 1]));
  }
}

/** Forget the upload made for `file` (it completed, or was cancelled). */
export function forgetUpload(file: File, metadata: Record<string, string>): void {
  localStorage.removeItem(createdKey(file, metadata));
}

/** Cancel an upload on the server: its bytes are deleted. */
export async function cancelUpload(url: string): Promise<void> {
  const response = await fetch(url, { method: "DELETE", headers: { ...authHeaders(), ...TUS_HEADERS } });
  if (!response.ok && response.status !== 404) {
    throw new Error(errorMessage(await response.json().catch(() => null), response.status));
  }
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
  uploadUrl: string | null = null,
): Promise<RunningUpload> {
  const digest = await fileSha256(file, callbacks.onHashing, body);
  const upload = new tus.Upload(body, {
    endpoint: "/api/v1/uploads",
    // An upload made already (createUpload): its bytes go there, from where it stopped.
    uploadUrl,
    chunkSize,
    retryDelays: RETRY_DELAYS_MS,
    metadata: { ...metadata, filename: file.name, sha256: digest },
    fingerprint: async () => fingerprintOf(file),
    storeFingerprintForResuming: uploadUrl === null,
    removeFingerprintOnSuccess: true,
    onBeforeRequest: (request) => {
      for (const [name, value] of Object.entries(authHeaders())) request.setHeader(name, value);
    },
    onUploadUrlAvailable: () => callbacks.onCreated?.(),
    onProgress: (sent, total) => callbacks.onProgress(sent, total),
    onShouldRetry: (error, attempt) => {
      const status = (error as tus.DetailedError).originalResponse?.getStatus() ?? 0;
      const retry = status === 0 || status >= 500 || status === 409 || status === 423;
      if (retry) callbacks.onRetry?.(t("upload.retrying", { reason: reasonOf(error), n: attempt + 1 }));
      return retry;
    },
    onSuccess: () => callbacks.onSuccess(upload.url ?? ""),
    onError: (error) => callbacks.onError(reasonOf(error)),
  });
  const previous = uploadUrl ? [] : await upload.findPreviousUploads();
  if (uploadUrl) {
    const head = await fetch(uploadUrl, { method: "HEAD", headers: { ...authHeaders(), ...TUS_HEADERS } }).catch(() => null);
    const offset = Number(head?.headers.get("Upload-Offset") ?? 0);
    if (head?.ok && offset > 0) callbacks.onResuming?.(offset, body.size);
  } else if (previous.length) {
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

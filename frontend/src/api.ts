// The REST API with the signed-in token; errors carry the server's plain-words reason.

import { currentLocale, t } from "./i18n";
import type { MapConfig } from "./types";

const TOKEN_KEY = "slidewatch.token";
const WHO_KEY = "slidewatch.who";

export class ApiError extends Error {
  constructor(
    readonly status: number,
    message: string,
  ) {
    super(message);
  }
}

export function errorMessage(body: unknown, status: number): string {
  const detail = (body as { detail?: unknown } | null)?.detail;
  if (typeof detail === "string") return detail;
  if (Array.isArray(detail)) {
    // FastAPI's validation errors: "field: what is wrong".
    return detail
      .map((d: { loc?: unknown[]; msg?: string }) => `${(d.loc ?? []).slice(1).join(".")}: ${d.msg ?? ""}`)
      .join("; ");
  }
  return t("error.serverAnswered", { status });
}

export const session = {
  get token(): string | null {
    return localStorage.getItem(TOKEN_KEY);
  },
  get who(): string | null {
    return localStorage.getItem(WHO_KEY);
  },
  set(token: string, who: string): void {
    localStorage.setItem(TOKEN_KEY, token);
    localStorage.setItem(WHO_KEY, who);
  },
  clear(): void {
    localStorage.removeItem(TOKEN_KEY);
    localStorage.removeItem(WHO_KEY);
  },
};

/** Called when the server no longer takes the token (expired, revoked). */
let onUnauthorized: () => void = () => {};
export function whenSignedOut(handler: () => void): void {
  onUnauthorized = handler;
}

export function authHeaders(): Record<string, string> {
  const token = session.token;
  return token ? { Authorization: `Bearer ${token}` } : {};
}

export async function api<T>(path: string, init: RequestInit = {}): Promise<T> {
  // The page's language goes with each request, for the answers the server words itself.
  const headers: Record<string, string> = {
    "Accept-Language": currentLocale(),
    ...authHeaders(),
    ...(init.headers as Record<string, string>),
  };
  if (init.body && typeof init.body === "string") headers["Content-Type"] = "application/json";
  const response = await fetch(path.startsWith("/") ? path : `/api/v1/${path}`, { ...init, headers });
  if (response.status === 401 && session.token) {
    session.clear();
    onUnauthorized();
  }
  if (!response.ok) {
    const body = await response.json().catch(() => null);
    throw new ApiError(response.status, errorMessage(body, response.status));
  }
  if (response.status === 204) return undefined as T;
  return (await response.json()) as T;
}

export const getJson = <T>(path: string) => api<T>(path);
export const postJson = <T>(path: string, body: unknown) => api<T>(path, { method: "POST", body: JSON.stringify(body) });
export const putJson = <T>(path: string, body: unknown) => api<T>(path, { method: "PUT", body: JSON.stringify(body) });

let config: Promise<MapConfig> | null = null;
export function mapConfig(): Promise<MapConfig> {
  config ??= fetch("/app-config.json").then((r) => r.json() as Promise<MapConfig>);
  return config;
}

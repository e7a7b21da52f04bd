// The REST API with the signed-in token; errors carry the server's plain-words reason
// (in English: on a page in another language, after a lead in that language).

import { currentLocale, type MessageKey, speaksServerLanguage, t } from "./i18n";
import type { MapConfig } from "./types";

const TOKEN_KEY = "slidewatch.token";
const WHO_KEY = "slidewatch.who";

export class ApiError extends Error {
  /** `message`: the refusal in the page's words; `detail`: the server's own, when it gave
   * some (a form that already says what failed shows only those). */
  constructor(
    readonly status: number,
    message: string,
    readonly detail: string | null = null,
  ) {
    super(message);
  }
}

/** The error an API response that is not OK becomes. */
export async function responseError(response: Response): Promise<ApiError> {
  const body = await response.json().catch(() => null);
  return new ApiError(response.status, errorMessage(body, response.status), detailText(body));
}

/** The server's words in an error's body (its `detail`); null when it gave none. */
function detailText(body: unknown): string | null {
  const detail = (body as { detail?: unknown } | null)?.detail;
  if (typeof detail === "string") return detail;
  if (Array.isArray(detail)) {
    // FastAPI's validation errors: "field: what is wrong".
    return detail
      .map((d: { loc?: unknown[]; msg?: string }) => `${(d.loc ?? []).slice(1).join(".")}: ${d.msg ?? ""}`)
      .join("; ");
  }
  return null;
}

/** What kind of refusal an HTTP status is, as the lead of the server's words. */
export function statusLead(status: number): MessageKey {
  if (status === 400 || status === 415 || status === 422) return "error.invalid";
  if (status === 401) return "error.signInAgain";
  if (status === 403) return "error.forbidden";
  if (status === 404 || status === 410) return "error.notFound";
  if (status === 409 || status === 412) return "error.conflict";
  if (status === 413) return "error.tooLarge";
  if (status === 429) return "error.tooMany";
  if (status === 503) return "error.unavailable";
  if (status >= 500) return "error.server";
  return "error.refused";
}

/** An error of the API in words: the server's own (English), as they are on an English
 * page; on a page in another language, after a lead in it that says what kind of
 * refusal it is (by the status), so that the reader knows what happened. */
export function errorMessage(body: unknown, status: number): string {
  const detail = detailText(body);
  if (speaksServerLanguage()) return detail ?? t("error.serverAnswered", { status });
  const lead = t(statusLead(status));
  return detail === null ? t("error.withStatus", { lead, status }) : t("error.withDetail", { lead, detail });
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
  if (!response.ok) throw await responseError(response);
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

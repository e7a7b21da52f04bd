// Small things every panel of a site's tools uses: a file saved with the token, a copy
// button, and the time zones to choose from.

import { ApiError, authHeaders, responseError } from "../api";
import { escapeHtml } from "../format";
import { t } from "../i18n";
import "./panels.css";

/** The IANA zones this browser knows (Intl), for a searchable list; UTC where it knows none. */
export function timeZones(): string[] {
  const supported = (Intl as unknown as { supportedValuesOf?: (k: string) => string[] }).supportedValuesOf;
  const zones = supported ? supported("timeZone") : [];
  return zones.includes("UTC") ? zones : ["UTC", ...zones];
}

/** An input that searches the zones as one types (a datalist), with the zones attached. */
export function timeZoneField(id: string, value: string, label: string): string {
  const options = timeZones()
    .map((z) => `<option value="${escapeHtml(z)}">`)
    .join("");
  return `<label for="${id}">${label}</label>
    <input id="${id}" list="${id}-zones" required autocomplete="off" spellcheck="false" value="${escapeHtml(value)}">
    <datalist id="${id}-zones">${options}</datalist>`;
}

export function isTimeZone(name: string): boolean {
  return timeZones().includes(name);
}

/** Save an API file: fetched with the token in its header (never in the URL), then saved
 * under the name the server gives (Content-Disposition) or `fallback`. */
export async function download(url: string, fallback: string): Promise<void> {
  const response = await fetch(url, { headers: authHeaders() });
  if (!response.ok) throw await responseError(response);
  const disposition = response.headers.get("Content-Disposition") ?? "";
  const named = /filename="?([^";]+)"?/.exec(disposition)?.[1];
  const link = document.createElement("a");
  link.href = URL.createObjectURL(await response.blob());
  link.download = named ?? fallback;
  document.body.append(link);
  link.click();
  link.remove();
  // Revoked later: the browser reads the blob after click() returns.
  setTimeout(() => URL.revokeObjectURL(link.href), 60_000);
}

/** Put `text` on the clipboard; falls back to a selected field where the API is missing
 * (plain http on another host than localhost has no navigator.clipboard). */
export async function copyText(text: string, field?: HTMLInputElement): Promise<boolean> {
  try {
    await navigator.clipboard.writeText(text);
    return true;
  } catch {
    if (!field) return false;
    field.focus();
    field.select();
    return document.execCommand("copy");
  }
}

export function failure(e: unknown): string {
  return e instanceof ApiError ? e.message : t("error.unreachable");
}

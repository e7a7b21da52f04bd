import { api, session } from "../api";
import { escapeHtml } from "../format";

/** The top bar: where we are, who is signed in, sign out. */
export function header(crumbs: string): string {
  return `<header class="topbar">
    <nav aria-label="Breadcrumb">${crumbs}</nav>
    <div class="who">Signed in as <strong>${escapeHtml(session.who ?? "")}</strong>
      <button type="button" id="sign-out">Sign out</button></div>
  </header>`;
}

export function wireSignOut(root: HTMLElement): void {
  root.querySelector("#sign-out")?.addEventListener("click", async () => {
    await api("auth/sign-out", { method: "POST" }).catch(() => undefined);
    session.clear();
    location.hash = "#/";
    location.reload();
  });
}

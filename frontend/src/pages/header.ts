import { api, session } from "../api";
import { escapeHtml } from "../format";
import { t } from "../i18n";
import { languageSelectHtml, wireLanguageSelect } from "../i18n/selector";

const SIGN_IN_NOTICE = "slidewatch.sign-in-notice";

/** Kept until dismissed: what the server told, at sign-in, of failed sign-ins to the account. */
export function keepSignInNotice(notice: string | null): void {
  if (notice) sessionStorage.setItem(SIGN_IN_NOTICE, notice);
  else sessionStorage.removeItem(SIGN_IN_NOTICE);
}

/** The top bar: where we are, who is signed in, the account, the language, sign out; and
 * the sign-in notice, if there is one. */
export function header(crumbs: string): string {
  const notice = sessionStorage.getItem(SIGN_IN_NOTICE);
  return `<header class="topbar">
    <nav aria-label="Breadcrumb">${crumbs}</nav>
    <div class="who">${t("header.signedInAs", { who: `<strong>${escapeHtml(session.who ?? "")}</strong>` })}
      <a href="#/account">${t("header.account")}</a>
      ${languageSelectHtml()}
      <button type="button" id="sign-out">${t("header.signOut")}</button></div>
  </header>${
    notice
      ? `<p class="notice" role="status" id="sign-in-notice">${escapeHtml(notice)}
          <button type="button" id="dismiss-notice">${t("header.dismiss")}</button></p>`
      : ""
  }`;
}

export function wireSignOut(root: HTMLElement): void {
  wireLanguageSelect(root);
  root.querySelector("#dismiss-notice")?.addEventListener("click", () => {
    keepSignInNotice(null);
    root.querySelector("#sign-in-notice")?.remove();
  });
  root.querySelector("#sign-out")?.addEventListener("click", async () => {
    await api("auth/sign-out", { method: "POST" }).catch(() => undefined);
    session.clear();
    keepSignInNotice(null);
    location.hash = "#/";
    location.reload();
  });
}

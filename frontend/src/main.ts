// slidewatch's map: sign in, the list of sites, a site's page. Routes live in the URL's
// hash (#/sites/3) so that the backend serves one index.html for all of them.

import { mapConfig, session, whenSignedOut } from "./api";
import { currentLanguage, onLanguageChange, t } from "./i18n";
import { renderAccount } from "./pages/account";
import { renderSignIn } from "./pages/signin";
import { renderSite } from "./pages/site";
import { renderSites } from "./pages/sites";
import "./styles.css";

const app = document.getElementById("app") as HTMLElement;
let leave: (() => void) | null = null;

async function route(): Promise<void> {
  leave?.();
  leave = null;
  const hash = location.hash.replace(/^#/, "") || "/";
  if (!session.token) {
    renderSignIn(app, () => {
      // A changed hash routes by its event; routing here too drew the page twice, and
      // the second drawing dropped what the user had begun to type.
      const target = hash === "/sign-in" ? "#/" : `#${hash}`;
      if (location.hash === target) void route();
      else location.hash = target;
    });
    return;
  }
  const config = await mapConfig();
  const site = /^\/sites\/(\d+)$/.exec(hash);
  if (site) leave = await renderSite(app, Number(site[1]), config);
  else if (hash === "/account") await renderAccount(app);
  else renderSites(app);
}

/** What the page is in: <html lang>, its title's and the skip link's words. */
function speak(): void {
  document.documentElement.lang = currentLanguage();
  const skip = document.querySelector(".skip-link");
  if (skip) skip.textContent = t("page.skipToContent");
}

whenSignedOut(() => {
  sessionStorage.setItem("slidewatch.notice", t("signIn.sessionEnded"));
  void route();
});
// Another language chosen: the page drawn again in it (no reload, nothing typed is kept).
onLanguageChange(() => {
  speak();
  void route();
});
speak();
window.addEventListener("hashchange", () => void route());
void route();

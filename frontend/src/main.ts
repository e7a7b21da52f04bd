// slidewatch's map: sign in, the list of sites, a site's page. Routes live in the URL's
// hash (#/sites/3) so that the backend serves one index.html for all of them.

import { mapConfig, session, whenSignedOut } from "./api";
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
      location.hash = hash === "/sign-in" ? "#/" : `#${hash}`;
      void route();
    });
    return;
  }
  const config = await mapConfig();
  const site = /^\/sites\/(\d+)$/.exec(hash);
  if (site) leave = await renderSite(app, Number(site[1]), config);
  else if (hash === "/account") await renderAccount(app);
  else renderSites(app);
}

whenSignedOut(() => {
  sessionStorage.setItem("slidewatch.notice", "Your session has ended: sign in again.");
  void route();
});
window.addEventListener("hashchange", () => void route());
void route();

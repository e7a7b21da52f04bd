// The language selector of the top bar and the sign-in page: each language by its own
// name; a choice is kept and the page speaks it at once.

import { escapeHtml } from "../format";
import { chooseLanguage, currentLanguage, languages, t } from "./index";
import "./language.css";

export function languageSelectHtml(): string {
  const options = languages()
    .map(
      (l) =>
        `<option value="${escapeHtml(l.code)}" lang="${escapeHtml(l.code)}"${l.code === currentLanguage() ? " selected" : ""}>${escapeHtml(l.name)}</option>`,
    )
    .join("");
  // Named in both the page's language and English: whoever cannot read the one finds the other.
  return `<select id="language-select" class="language" aria-label="${escapeHtml(t("header.language"))}">${options}</select>`;
}

export function wireLanguageSelect(root: HTMLElement): void {
  const select = root.querySelector<HTMLSelectElement>("#language-select");
  select?.addEventListener("change", () => chooseLanguage(select.value));
}

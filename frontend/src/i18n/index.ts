// The page's words in the user's language: `t(key, params)` looks a message up in the
// chosen language's catalogue (messages/*.ts, each picked up by itself), fills in its
// parameters and picks its plural form. The language is the user's choice (kept in
// localStorage) or else the first of the browser's languages that has a catalogue.

import type { Catalogue, Message, MessageKey } from "./catalogue";

export type { MessageKey } from "./catalogue";

const CHOICE_KEY = "slidewatch.language";
const FALLBACK = "en";

/** Every language file in messages/, by its code: adding a language is adding a file. */
const CATALOGUES: Map<string, Catalogue> = new Map(
  Object.values(import.meta.glob<Catalogue>("./messages/*.ts", { eager: true, import: "default" })).map((c) => [
    c.code,
    c,
  ]),
);

export interface Language {
  code: string;
  name: string;
}

/** The languages the page speaks, English first. */
export function languages(): Language[] {
  return [...CATALOGUES.values()]
    .map((c) => ({ code: c.code, name: c.name }))
    .sort((a, b) => (a.code === FALLBACK ? -1 : b.code === FALLBACK ? 1 : a.code.localeCompare(b.code)));
}

const primary = (tag: string) => tag.toLowerCase().split(/[-_]/)[0];

/** The locale to speak and format in: the chosen language (or else the first of the
 * browser's languages the page has), with the browser's region of it for dates and
 * numbers ("en-US" formats differ from "en-GB"), or the language's own default region. */
export function resolveLocale(preferred: readonly string[], chosen: string | null): string {
  const language =
    chosen && CATALOGUES.has(chosen) ? chosen : (preferred.map(primary).find((code) => CATALOGUES.has(code)) ?? FALLBACK);
  const regional = preferred.find((tag) => primary(tag) === language && tag.includes("-"));
  const locale = regional ?? (CATALOGUES.get(language) as Catalogue).locale;
  try {
    return Intl.getCanonicalLocales(locale)[0];
  } catch {
    return (CATALOGUES.get(language) as Catalogue).locale;
  }
}

function storedChoice(): string | null {
  try {
    return localStorage.getItem(CHOICE_KEY);
  } catch {
    return null; // storage refused (a private window's settings): the browser's languages
  }
}

function browserLanguages(): readonly string[] {
  return typeof navigator === "undefined" ? [] : navigator.languages?.length ? navigator.languages : [navigator.language];
}

let locale = resolveLocale(browserLanguages(), storedChoice());
let catalogue = CATALOGUES.get(primary(locale)) as Catalogue;
let pluralRules = new Intl.PluralRules(locale);
const listeners: Array<() => void> = [];

/** The locale of the page's words, dates and numbers ("en-GB", "ja-JP"). */
export function currentLocale(): string {
  return locale;
}

/** The language code of the page's words ("en", "ja"). */
export function currentLanguage(): string {
  return catalogue.code;
}

/** Speak `code` from now on (and after a reload); null: follow the browser again. */
export function chooseLanguage(code: string | null): void {
  try {
    if (code) localStorage.setItem(CHOICE_KEY, code);
    else localStorage.removeItem(CHOICE_KEY);
  } catch {
    /* not kept: this page still speaks it */
  }
  useLocale(resolveLocale(browserLanguages(), code));
}

/** Speak and format in `tag` (a locale whose language has a catalogue). */
export function useLocale(tag: string): void {
  locale = resolveLocale([tag], null);
  catalogue = CATALOGUES.get(primary(locale)) as Catalogue;
  pluralRules = new Intl.PluralRules(locale);
  if (typeof document !== "undefined") document.documentElement.lang = catalogue.code;
  for (const listener of listeners) listener();
}

/** Called after the language changes (the page draws itself again). */
export function onLanguageChange(listener: () => void): void {
  listeners.push(listener);
}

export type Params = Record<string, string | number>;

/** The form of `message` for `count` in the current language. */
function form(message: Message, count: number | undefined): string {
  if (typeof message === "string") return message;
  if (count === undefined) return message.other;
  return message[pluralRules.select(count)] ?? message.other;
}

/** The message `key` in the current language, its `{param}`s filled in; the plural form
 * chosen by `params.count`. Numbers go in as they are (ids, counts): a measure is
 * formatted first (format.ts). English stands in for a message a language lacks.
 * Parameters are text: escape them where the result is HTML. */
export function t(key: MessageKey, params: Params = {}): string {
  const message = catalogue.messages[key] ?? (CATALOGUES.get(FALLBACK) as Catalogue).messages[key];
  const count = typeof params.count === "number" ? params.count : undefined;
  return form(message, count).replace(/\{(\w+)\}/g, (whole, name: string) => {
    const value = params[name];
    return value === undefined ? whole : String(value);
  });
}

/** The language the server writes its own words in: method summaries, stage help,
 * survey warnings, quality checks, job failures and the API's error details. */
export const SERVER_LANGUAGE = "en";

/** Whether the page speaks the server's language: its words are shown as it wrote them,
 * with no translation and no lead. */
export function speaksServerLanguage(): boolean {
  return catalogue.code === SERVER_LANGUAGE;
}

/** The words for something the server names by an identifier and words itself (a
 * detection method's summary, a stage's name and help): the server's own words where the
 * page speaks its language; else the message `key` of the page's language; else, for an
 * identifier no catalogue knows (a method added on the server since), the server's. */
export function serverWords(key: string, server: string): string {
  if (speaksServerLanguage()) return server;
  const message = Object.hasOwn(catalogue.messages, key) ? catalogue.messages[key as MessageKey] : undefined;
  return message === undefined ? server : form(message, undefined);
}

/** A message the server words from a catalogue key and its figures (a quality check's
 * `text`), in the page's language: null where the page speaks the server's language (its
 * own words are the same) or the catalogue lacks the key. */
export function serverMessage(key: string, params: Params): string | null {
  if (speaksServerLanguage() || !Object.hasOwn(catalogue.messages, key)) return null;
  return t(key as MessageKey, params);
}

/** Free text the server wrote (a job's failure, a quality check's message) where the
 * page speaks another language: marked as the server's own words, in its language. */
export function serverText(text: string): string {
  return speaksServerLanguage() ? text : t("server.original", { text });
}

/** Every catalogue, for tests (completeness of each language against English). */
export function catalogues(): Catalogue[] {
  return [...CATALOGUES.values()];
}

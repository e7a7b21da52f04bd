// The shape of a language's file in messages/: its code, its own name, the locale its
// dates and numbers take when the browser names no region of it, and every message.
// English (messages/en.ts) is the reference: its keys are the keys of every language.

import type { messages as english } from "./messages/en";

/** A text, or one text per plural category of the language (Intl.PluralRules): the form
 * is chosen by the `count` parameter. `{name}` in a text is replaced by that parameter. */
export type Message = string | ({ other: string } & Partial<Record<Intl.LDMLPluralRule, string>>);

export type MessageKey = keyof typeof english;

/** Every key of English, no other: tsc refuses a language file that misses one. */
export type Messages = Record<MessageKey, Message>;

export interface Catalogue {
  /** The language subtag it is for ("en", "ja"): matched with the browser's languages. */
  code: string;
  /** The language's name in itself, for the selector ("日本語"). */
  name: string;
  /** Dates and numbers when the browser names no region of the language ("ja-JP"). */
  locale: string;
  messages: Messages;
}

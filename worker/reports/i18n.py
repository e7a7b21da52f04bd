"""Message catalogues of the reports and e-mails, one JSON file per language, with the
language's own formats for numbers, dates and times.

`worker/reports/catalogues/{code}.json` holds, for one language:

    "language": {"code", "name" (in the language itself), "decimal", "group", "time"
                 (a date and time: year month day hour minute zone), "plural_one",
                 "pdf_word_wrap"}
    "messages": {"report.title": "…{site}…", "summary.text": {"one": …, "other": …}, …}

A message is a `str.format` text with named parameters; a message whose wording depends on
a count has one text per plural category: "other" always, and "one" where `plural_one`
lists the counts that take it ([1] in English, none in Japanese). A new language is one
more file with every key of the others and the same parameters in each
(tests/reports/test_catalogues.py checks both).
"""

from __future__ import annotations

import json
import string
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import cache
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

CATALOGUES = Path(__file__).parent / "catalogues"
DEFAULT_LANGUAGE = "en"


class UnknownLanguage(ValueError):
    """A language with no catalogue; the message names those there are."""


@dataclass(frozen=True)
class Catalogue:
    code: str
    name: str  # in the language itself: "English", "日本語"
    decimal: str  # decimal sign
    group: str  # thousands separator
    time_pattern: str  # fields: year month day hour minute zone
    plural_one: tuple[int, ...]  # counts that take the "one" form
    pdf_word_wrap: str | None  # reportlab's wordWrap: "CJK" lets a line break anywhere
    messages: dict[str, str | dict[str, str]]

    def text(self, key: str, /, **params: Any) -> str:
        """The message `key` with its parameters filled in as given: ids as they are,
        measurements formatted with `number` first.

        A message with plural forms takes the form for the int `count`."""
        entry = self.messages[key]
        if isinstance(entry, dict):
            count = abs(int(params["count"]))
            entry = entry["one"] if count in self.plural_one else entry["other"]
        return entry.format(**params)

    def number(self, value: float, decimals: int, signed: bool = False) -> str:
        """`value` rounded to `decimals`, with the language's decimal sign and grouping."""
        sign = "+" if signed else ""
        plain = f"{value:{sign},.{decimals}f}"  # "1,234.5": swapped below in one pass
        return plain.translate(str.maketrans({",": self.group, ".": self.decimal}))

    def time(self, moment: datetime, timezone: str = "UTC") -> str:
        """The time in the site's zone, named: "2026-06-01 19:00 JST", "2026年6月1日 19:00 JST"."""
        local = _in_zone(moment, timezone)
        return self.time_pattern.format(
            year=local.year,
            month=local.month,
            day=local.day,
            hour=local.hour,
            minute=local.minute,
            zone=local.strftime("%Z"),
        )


def _in_zone(moment: datetime, timezone: str) -> datetime:
    moment = moment if moment.tzinfo else moment.replace(tzinfo=UTC)
    try:
        zone = ZoneInfo(timezone)
    except (ZoneInfoNotFoundError, ValueError):
        zone = ZoneInfo("UTC")  # still readable; the zone's name is shown with the time
    return moment.astimezone(zone)


def available_languages() -> list[str]:
    """The codes of the languages with a catalogue, sorted: ["en", "ja"]."""
    return sorted(path.stem for path in CATALOGUES.glob("*.json"))


def check_language(code: str) -> str:
    """`code` if it has a catalogue; else UnknownLanguage naming those that do."""
    if code not in available_languages():
        allowed = ", ".join(available_languages())
        raise UnknownLanguage(f"unknown language {code!r}: use one of {allowed}")
    return code


@cache
def catalogue(code: str = DEFAULT_LANGUAGE) -> Catalogue:
    """The catalogue of a language (UnknownLanguage if there is none)."""
    check_language(code)
    values = json.loads((CATALOGUES / f"{code}.json").read_text(encoding="utf-8"))
    meta = values["language"]
    return Catalogue(
        code=meta["code"],
        name=meta["name"],
        decimal=meta["decimal"],
        group=meta["group"],
        time_pattern=meta["time"],
        plural_one=tuple(meta["plural_one"]),
        pdf_word_wrap=meta.get("pdf_word_wrap"),
        messages=values["messages"],
    )


def parameters(message: str | dict[str, str]) -> set[str]:
    """The named parameters a message uses (over all its plural forms)."""
    texts = message.values() if isinstance(message, dict) else [message]
    return {
        field.split(".")[0].split("[")[0]
        for text in texts
        for _literal, field, _spec, _conversion in string.Formatter().parse(text)
        if field
    }

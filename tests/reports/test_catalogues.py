"""The message catalogues of reports and e-mails: every language has every key with the
same parameters, its plural forms, and its own number and time formats."""

import json
from datetime import UTC, datetime

import pytest

from worker.reports.i18n import (
    CATALOGUES,
    UnknownLanguage,
    available_languages,
    catalogue,
    check_language,
    parameters,
)

LANGUAGES = available_languages()


def test_english_and_japanese_are_there() -> None:
    assert LANGUAGES == ["en", "ja"]
    assert [catalogue(code).name for code in LANGUAGES] == ["English", "日本語"]


@pytest.mark.parametrize("code", LANGUAGES)
def test_every_catalogue_has_every_key_with_the_same_parameters(code: str) -> None:
    reference = catalogue("en").messages
    messages = catalogue(code).messages
    assert sorted(messages) == sorted(reference)
    for key, message in messages.items():
        assert parameters(message) == parameters(reference[key]), key
        if isinstance(message, dict):
            # "other" always; "one" where the language has a singular, nothing else.
            needed = {"other", "one"} if catalogue(code).plural_one else {"other"}
            assert set(message) == needed, key


@pytest.mark.parametrize("code", LANGUAGES)
def test_a_catalogue_file_is_named_by_its_code_and_describes_its_language(code: str) -> None:
    values = json.loads((CATALOGUES / f"{code}.json").read_text(encoding="utf-8"))
    assert values["language"]["code"] == code
    assert set(values["language"]) == {
        "code", "name", "decimal", "group", "time", "plural_one", "pdf_word_wrap",
    }  # fmt: skip
    words = catalogue(code)
    # Every message fills in with its parameters (a typo in a brace would raise here).
    for key, message in words.messages.items():
        params: dict = {name: "x" for name in parameters(message)}
        if isinstance(message, dict) or "count" in params:
            params["count"] = 2  # what picks a plural form
        assert words.text(key, **params)


def test_numbers_times_and_plurals_follow_the_language() -> None:
    en, ja = catalogue("en"), catalogue("ja")
    assert en.number(12345.678, 1) == "12,345.7" and ja.number(12345.678, 1) == "12,345.7"
    assert en.number(-3.25, 1, signed=True) == "-3.2" and en.number(4, 0, signed=True) == "+4"
    moment = datetime(2026, 11, 26, 8, 30, tzinfo=UTC)
    assert en.time(moment, "Asia/Tokyo") == "2026-11-26 17:30 JST"
    assert ja.time(moment, "Asia/Tokyo") == "2026年11月26日 17:30 JST"
    assert ja.time(moment, "Europe/Rome") == "2026年11月26日 09:30 CET"
    summary = {"area": "1", "loss": "2", "gain": "3", "dh": "4"}
    assert en.text("report.summary_text", count=1, **summary).startswith("1 landslide detected")
    assert en.text("report.summary_text", count=3, **summary).startswith("3 landslides detected")
    assert ja.text("report.summary_text", count=1, **summary).startswith("地すべりを 1 箇所検出")


def test_an_unknown_language_is_refused_naming_those_there_are() -> None:
    assert check_language("ja") == "ja"
    with pytest.raises(UnknownLanguage, match="unknown language 'fr': use one of en, ja"):
        check_language("fr")
    with pytest.raises(UnknownLanguage):
        catalogue("../en")

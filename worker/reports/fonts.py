"""Fonts of the reports: DejaVu Sans for Latin, Greek and the symbols ("Δh", "m²", "−"),
and a Japanese font for every character DejaVu has no glyph for, chosen character by
character: a Japanese report, or a Japanese site name in an English one, renders and can
be extracted as text.

DejaVu Sans comes with matplotlib. The Japanese font is IPAex Gothic, Debian's
fonts-ipaexfont-gothic (scripts/install-system-packages.sh installs it); both are
TrueType, embedded as subsets. Where it is missing, reportlab's built-in HeiseiKakuGo-W5
stands in: not embedded, so the reader's own Japanese font draws it.
"""

from __future__ import annotations

import logging
from functools import cache
from html import escape
from pathlib import Path

import matplotlib
from reportlab.pdfbase import pdfmetrics
from reportlab.pdfbase.cidfonts import UnicodeCIDFont
from reportlab.pdfbase.ttfonts import TTFont

log = logging.getLogger(__name__)

FONT, FONT_BOLD = "DejaVuSans", "DejaVuSans-Bold"
JAPANESE_FONT = "IPAexGothic"
JAPANESE_FONT_STAND_IN = "HeiseiKakuGo-W5"
JAPANESE_FONT_FILES = (
    Path("/usr/share/fonts/opentype/ipaexfont-gothic/ipaexg.ttf"),
    Path("/usr/share/fonts/truetype/fonts-japanese-gothic.ttf"),  # Debian's alternative
)
DEJAVU_FILES = Path(matplotlib.get_data_path()) / "fonts" / "ttf"


def japanese_font_file() -> Path | None:
    return next((path for path in JAPANESE_FONT_FILES if path.is_file()), None)


@cache
def register_fonts() -> str:
    """Register the PDF's fonts with reportlab (once); return the Japanese font's name."""
    pdfmetrics.registerFont(TTFont(FONT, str(DEJAVU_FILES / "DejaVuSans.ttf")))
    pdfmetrics.registerFont(TTFont(FONT_BOLD, str(DEJAVU_FILES / "DejaVuSans-Bold.ttf")))
    pdfmetrics.registerFontFamily(FONT, normal=FONT, bold=FONT_BOLD)
    found = japanese_font_file()
    if found is None:
        log.warning(
            "no Japanese font (%s): Japanese text uses %s, not embedded; install Debian's "
            "fonts-ipaexfont-gothic",
            JAPANESE_FONT_FILES[0],
            JAPANESE_FONT_STAND_IN,
        )
        pdfmetrics.registerFont(UnicodeCIDFont(JAPANESE_FONT_STAND_IN))
        return JAPANESE_FONT_STAND_IN
    pdfmetrics.registerFont(TTFont(JAPANESE_FONT, str(found)))
    return JAPANESE_FONT


@cache
def _dejavu_characters() -> frozenset[int]:
    register_fonts()
    return frozenset(pdfmetrics.getFont(FONT).face.charToGlyph)


def markup(text: str) -> str:
    """`text` escaped for a reportlab Paragraph, each run of characters DejaVu Sans lacks
    set in the Japanese font (a font of reportlab draws only its own glyphs)."""
    fallback = register_fonts()
    has_glyph = _dejavu_characters()
    runs: list[tuple[bool, str]] = []  # (needs the Japanese font, characters)
    for character in str(text):
        foreign = ord(character) not in has_glyph and not character.isspace()
        if runs and runs[-1][0] == foreign:
            runs[-1] = (foreign, runs[-1][1] + character)
        else:
            runs.append((foreign, character))
    return "".join(
        f'<font name="{fallback}">{escape(run, quote=False)}</font>'
        if foreign
        else escape(run, quote=False)
        for foreign, run in runs
    )


@cache
def matplotlib_families() -> list[str]:
    """Font families for matplotlib: DejaVu Sans, then the Japanese font (matplotlib falls
    back glyph by glyph along the list)."""
    found = japanese_font_file()
    if found is None:
        return ["DejaVu Sans"]
    from matplotlib import font_manager

    font_manager.fontManager.addfont(str(found))
    return ["DejaVu Sans", font_manager.FontProperties(fname=str(found)).get_name()]

"""Fonts of the reports: DejaVu Sans for Latin, Greek and the symbols ("Δh", "m²", "−"),
and a Japanese font for every character DejaVu has no glyph for, chosen character by
character: a Japanese report, or a Japanese site name in an English one, renders and can
be extracted as text.

DejaVu Sans comes with matplotlib. The Japanese font is IPAex Gothic, Debian's
fonts-ipaexfont-gothic (scripts/install-system-packages.sh and the Dockerfile install it);
both are TrueType, embedded as subsets. Where it is missing, a report with Japanese text
fails at once and says so, rather than print empty boxes; one without is made as before.
"""

from __future__ import annotations

from functools import cache
from html import escape
from importlib.util import find_spec
from pathlib import Path

from reportlab.pdfbase import pdfmetrics
from reportlab.pdfbase.ttfonts import TTFont

from worker.pipeline.errors import InputError

FONT, FONT_BOLD = "DejaVuSans", "DejaVuSans-Bold"
JAPANESE_FONT = "IPAexGothic"
JAPANESE_FONT_FILES = (
    Path("/usr/share/fonts/opentype/ipaexfont-gothic/ipaexg.ttf"),
    Path("/usr/share/fonts/truetype/fonts-japanese-gothic.ttf"),  # Debian's alternative
)


@cache
def dejavu_file(name: str) -> str:
    """A DejaVu font file of matplotlib's, found without importing matplotlib (most of a
    second, in every worker and API process that only might make a report)."""
    spec = find_spec("matplotlib")
    if spec is None or not spec.submodule_search_locations:
        raise RuntimeError("matplotlib, whose DejaVu fonts reports use, is not installed")
    package = Path(next(iter(spec.submodule_search_locations)))
    return str(package / "mpl-data" / "fonts" / "ttf" / name)


class FontMissing(InputError):
    """Text that needs the Japanese font, on a machine without it; says what to install."""


def japanese_font_file() -> Path | None:
    return next((path for path in JAPANESE_FONT_FILES if path.is_file()), None)


@cache
def register_fonts() -> bool:
    """Register the PDF's fonts with reportlab (once); say whether the Japanese one is."""
    pdfmetrics.registerFont(TTFont(FONT, dejavu_file("DejaVuSans.ttf")))
    pdfmetrics.registerFont(TTFont(FONT_BOLD, dejavu_file("DejaVuSans-Bold.ttf")))
    pdfmetrics.registerFontFamily(FONT, normal=FONT, bold=FONT_BOLD)
    found = japanese_font_file()
    if found is not None:
        pdfmetrics.registerFont(TTFont(JAPANESE_FONT, str(found)))
    return found is not None


@cache
def _dejavu_characters() -> frozenset[int]:
    return frozenset(TTFont(FONT, dejavu_file("DejaVuSans.ttf")).face.charToGlyph)


def markup(text: str) -> str:
    """`text` escaped for a reportlab Paragraph, each run of characters DejaVu Sans lacks
    set in the Japanese font (a font of reportlab draws only its own glyphs)."""
    has_japanese = register_fonts()
    has_glyph = _dejavu_characters()
    runs: list[tuple[bool, str]] = []  # (needs the Japanese font, characters)
    for character in str(text):
        foreign = ord(character) not in has_glyph and not character.isspace()
        if runs and runs[-1][0] == foreign:
            runs[-1] = (foreign, runs[-1][1] + character)
        else:
            runs.append((foreign, character))
    if not has_japanese and any(foreign for foreign, _ in runs):
        raise FontMissing(
            f"the report has text DejaVu Sans cannot draw ({text!r}) and this machine has no "
            f"Japanese font ({JAPANESE_FONT_FILES[0]}): install Debian's "
            "fonts-ipaexfont-gothic (make install does), then run the report again"
        )
    return "".join(
        f'<font name="{JAPANESE_FONT}">{escape(run, quote=False)}</font>'
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

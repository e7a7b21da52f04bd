"""The PDF's fonts: Japanese set in IPAex Gothic character by character, and a clear
failure, not empty boxes, on a machine without it."""

import pytest

from worker.reports import fonts


def test_japanese_runs_get_the_japanese_font_and_the_rest_stays_dejavu() -> None:
    assert fonts.register_fonts()  # make install puts IPAex Gothic on every machine
    assert (
        fonts.markup("East <flank> & Δh 2.5\u00a0m²") == "East &lt;flank&gt; &amp; Δh 2.5\u00a0m²"
    )
    assert fonts.markup("東斜面 (East flank)：地すべり 2 箇所") == (
        '<font name="IPAexGothic">東斜面</font> (East flank)'
        '<font name="IPAexGothic">：地すべり</font> 2 <font name="IPAexGothic">箇所</font>'
    )


def test_without_a_japanese_font_japanese_text_fails_saying_what_to_install(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(fonts, "register_fonts", lambda: False)
    assert fonts.markup("East flank, Δh") == "East flank, Δh"  # needs no Japanese font
    with pytest.raises(fonts.FontMissing, match="install Debian's fonts-ipaexfont-gothic"):
        fonts.markup("東斜面")

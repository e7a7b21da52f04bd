"""The survey quality verdict (worker/pipeline/quality.py): each check passes at its bound
and fails past it, checks that do not apply are not made, and report.json carries the
verdict with every failed check among its warnings."""

import json
import math
import re
from pathlib import Path

import pytest

from worker.pipeline.quality import QualityBounds, failed_messages, survey_quality
from worker.pipeline.reconstruction import write_report

RTK_SIGMA = [0.02, 0.02, 0.035]
# 3 x the stated horizontal sigma + 0.05 m (georef.check_stated_accuracy's defaults).
RTK_BOUND_H = 3 * math.hypot(0.02, 0.02) + 0.05


def segment(
    number: int = 0,
    after: tuple[float, float] = (0.3, 0.4),
    fit_residuals: tuple[float, float, float] = (0.03, 0.04, 0.05),
    stated: list[float] | None = None,
    within: bool | None = None,
) -> dict:
    east, north, up = fit_residuals
    return {
        "segment": number,
        "frames": 100,
        "fit": {
            "residuals_m": {"rms_east": east, "rms_north": north, "rms_up": up},
            "stated_sigma_m": stated,
            "within_stated_accuracy": within,
        },
        "residuals_after_m": {"rms_east": after[0], "rms_north": after[1], "rms_up": 0.5},
    }


def stages(*segments: dict, warnings: list[str] | None = None, **extra) -> dict:
    geo = {"crs": "EPSG:32632", "segments": list(segments), "warnings": warnings or []}
    geo.update(extra.pop("georeference", {}))
    out = {"georeference": geo}
    if "dsm" in extra:
        out["dsm"] = extra.pop("dsm")
    return out


def checks_by_name(quality: dict) -> dict[str, dict]:
    return {c["name"]: c for c in quality["checks"]}


def test_stated_accuracy_reports_the_worst_segment_against_its_bound():
    ok = survey_quality(stages(segment(stated=RTK_SIGMA, within=True)))
    check = checks_by_name(ok)["georeference_accuracy"]
    assert check == {
        "name": "georeference_accuracy",
        "value": 0.05,  # hypot(0.03, 0.04)
        "bound": round(RTK_BOUND_H, 4),
        "passed": True,
        "message": check["message"],
        "text": {
            "key": "accuracy.within",
            "figures": {"segment": "", "rms_h": "0.05", "bound_h": f"{RTK_BOUND_H:.2f}"},
        },
    }
    assert "0.05 m" in check["message"] and "0.13 m" in check["message"]
    assert ok["passed"] is True
    # A log that states an accuracy is not also held to the stand-alone GPS bound.
    assert "georeference_residual" not in checks_by_name(ok)

    missed = survey_quality(
        stages(
            segment(0, stated=RTK_SIGMA, within=True),
            segment(1, fit_residuals=(0.12, 0.16, 0.05), stated=RTK_SIGMA, within=False),
        )
    )
    check = checks_by_name(missed)["georeference_accuracy"]
    assert check["passed"] is False and missed["passed"] is False
    assert check["value"] == pytest.approx(0.2) and check["bound"] == round(RTK_BOUND_H, 4)
    assert "(segment 1)" in check["message"]
    assert "0.20 m (horizontal RMS)" in check["message"] and "allows 0.13 m" in check["message"]

    # Within horizontally, missed vertically (the georeference's verdict decides): the
    # message names the heights' figure and bound.
    vertical = survey_quality(
        stages(segment(fit_residuals=(0.03, 0.04, 0.4), stated=RTK_SIGMA, within=False))
    )
    check = checks_by_name(vertical)["georeference_accuracy"]
    assert check["passed"] is False
    assert "0.40 m (vertical RMS)" in check["message"] and "allows 0.16 m" in check["message"]

    # Missed over the positions that state an accuracy while the fit's figures over all of
    # them stay within: still a miss, said without a figure that contradicts it.
    hidden = survey_quality(stages(segment(stated=RTK_SIGMA, within=False)))
    check = checks_by_name(hidden)["georeference_accuracy"]
    assert check["passed"] is False and hidden["passed"] is False
    assert "further from the reconstruction than 3 times that accuracy" in check["message"]


def test_stand_alone_gps_residuals_pass_at_the_bound_and_fail_past_it():
    at_bound = checks_by_name(survey_quality(stages(segment(after=(3.0, 4.0)))))
    check = at_bound["georeference_residual"]
    assert check["value"] == 5.0 and check["bound"] == 5.0 and check["passed"] is True
    assert "georeference_accuracy" not in at_bound  # the log states no accuracy

    past = survey_quality(stages(segment(0), segment(1, after=(3.0, 4.01))))
    check = checks_by_name(past)["georeference_residual"]
    assert check["passed"] is False and past["passed"] is False
    assert check["value"] == pytest.approx(math.hypot(3.0, 4.01), abs=1e-4)
    assert "5.01 m (horizontal RMS)" in check["message"] and "5.0 m allowed" in check["message"]
    assert "(segment 1)" in check["message"]

    # The bound is an option.
    strict = survey_quality(
        stages(segment(after=(0.6, 0.8))), QualityBounds(max_standalone_residual_m=0.5)
    )
    assert checks_by_name(strict)["georeference_residual"]["passed"] is False


def test_overlap_coverage_passes_at_the_bound_and_is_not_checked_without_the_figure():
    at_bound = survey_quality(stages(segment(), dsm={"overlap_coverage": 0.8}))
    check = checks_by_name(at_bound)["overlap_coverage"]
    assert check["value"] == 0.8 and check["bound"] == 0.8 and check["passed"] is True
    below = survey_quality(stages(segment(), dsm={"overlap_coverage": 0.79}))
    check = checks_by_name(below)["overlap_coverage"]
    assert check["passed"] is False and below["passed"] is False
    assert check["message"].startswith("Only 79% of the area seen by two or more cameras")
    assert "below the 80% needed" in check["message"]
    for dsm in ({}, {"overlap_coverage": None}):
        assert "overlap_coverage" not in checks_by_name(survey_quality(stages(segment(), dsm=dsm)))


def test_dropped_segments_are_counted_and_pass_while_one_remains():
    whole = checks_by_name(survey_quality(stages(segment())))["segments_dropped"]
    assert whole["value"] == 0 and whole["passed"] is True and whole["bound"] is None
    dropped = survey_quality(
        stages(
            segment(0),
            warnings=[
                "segment 1 left out: only 3 camera positions fall within the flight log's "
                "time span",
                "segment 2 left out: the aircraft moved only 1.0 m during the video",
                "the time offset is uncertain",
            ],
        )
    )
    check = checks_by_name(dropped)["segments_dropped"]
    assert check["value"] == 2 and check["passed"] is True and dropped["passed"] is True
    assert check["message"].startswith("2 of 3 flight segments could not be placed")
    assert "other 1 covered" in check["message"]
    assert failed_messages(dropped) == []


def test_photo_outliers_pass_at_a_fifth_and_fail_past_it():
    def photos(outliers: int, total: int = 10) -> list[dict]:
        return [
            {"name": f"DJI_{i:04d}.JPG", "status": "outlier" if i < outliers else "used"}
            for i in range(total)
        ]

    at_bound = survey_quality(stages(segment(), georeference={"photos": photos(2)}))
    check = checks_by_name(at_bound)["photo_outliers"]
    assert check["value"] == 0.2 and check["bound"] == 0.2 and check["passed"] is True
    past = survey_quality(stages(segment(), georeference={"photos": photos(3)}))
    check = checks_by_name(past)["photo_outliers"]
    assert check["value"] == 0.3 and check["passed"] is False and past["passed"] is False
    assert check["message"].startswith("3 of 10 photos (30%)") and "20%" in check["message"]
    # A video survey has no photos to check.
    assert "photo_outliers" not in checks_by_name(survey_quality(stages(segment())))


def test_a_photo_sets_scale_and_rotation_are_checked_against_two_dsm_cells():
    def photo_segment(at_edge_m: float) -> dict:
        seg = segment()
        seg["fit"]["shape_sigma"] = {"scale": 0.0017, "rotation_deg": 0.1, "at_edge_m": at_edge_m}
        return seg

    dsm = {"dsm": {"resolution_m": 0.02}}
    at_bound = survey_quality(stages(photo_segment(0.04), dsm=dsm))
    check = checks_by_name(at_bound)["georeference_shape"]
    assert check["value"] == 0.04 and check["bound"] == 0.04 and check["passed"] is True
    past = survey_quality(stages(photo_segment(0.071), dsm=dsm))
    check = checks_by_name(past)["georeference_shape"]
    assert check["passed"] is False and past["passed"] is False
    assert "0.17 %" in check["message"] and "7.1 cm at the site's edge" in check["message"]
    assert "2 DSM cells (4.0 cm)" in check["message"]
    # A video survey (no shape figure) and a DSM without its cell size are not checked.
    assert "georeference_shape" not in checks_by_name(survey_quality(stages(segment(), dsm=dsm)))
    no_cell = survey_quality(stages(photo_segment(0.071), dsm={"dsm": {}}))
    assert "georeference_shape" not in checks_by_name(no_cell)


def test_dense_heights_that_disagree_by_more_than_three_cells_fail_the_verdict():
    def dsm(agreement_m: float, cell_m: float = 0.05) -> dict:
        figures = {"agreement_m": agreement_m, "cells": 5000, "points_used": 10**5}
        return {"dsm": {"resolution_m": cell_m}, "height_agreement": figures}

    at_bound = survey_quality(stages(segment(), dsm=dsm(0.15)))
    check = checks_by_name(at_bound)["height_agreement"]
    assert check["value"] == 0.15 and check["bound"] == 0.15 and check["passed"] is True
    # A hillslope flown at 144 m with 16-m baselines: 2.2 m where the cells are 0.5 m.
    past = survey_quality(stages(segment(), dsm=dsm(2.2, cell_m=0.5)))
    check = checks_by_name(past)["height_agreement"]
    assert check["passed"] is False and past["passed"] is False
    assert "220.0 cm (1 sigma), 4.4 DSM cells, more than the 3 allowed" in check["message"]
    assert check["message"] in failed_messages(past)
    # Without dense points (no figure) the check is not made.
    no_figure = survey_quality(stages(segment(), dsm={"dsm": {"resolution_m": 0.05}}))
    assert "height_agreement" not in checks_by_name(no_figure)


def test_report_carries_the_verdict_and_each_failed_check_among_its_warnings(tmp_path):
    geo = stages(segment(after=(6.0, 8.0)), warnings=["the time offset is uncertain"])
    (tmp_path / "georeference.json").write_text(json.dumps(geo["georeference"]))
    (tmp_path / "dsm.json").write_text(json.dumps({"overlap_coverage": 0.9, "warnings": []}))
    report = write_report(tmp_path)
    assert json.loads((tmp_path / "report.json").read_text())["quality"] == report["quality"]
    quality = report["quality"]
    assert quality["passed"] is False
    assert [c["name"] for c in quality["checks"]] == [
        "georeference_residual",
        "overlap_coverage",
        "segments_dropped",
    ]
    (miss,) = failed_messages(quality)
    assert "10.00 m (horizontal RMS)" in miss
    assert report["warnings"] == ["the time offset is uncertain", miss]


EN_CATALOGUE = Path(__file__).parents[2] / "frontend/src/i18n/messages/en.ts"


def _english_templates() -> dict[str, dict[str, str]]:
    """The page's English `qualityText.*` messages: key -> {form: template}."""
    text = EN_CATALOGUE.read_text()
    found: dict[str, dict[str, str]] = {}
    entry = re.compile(r'"qualityText\.([\w.]+)": (\{\n.*?\n  \}|"[^"]*")', re.DOTALL)
    for key, body in entry.findall(text):
        if body.startswith("{"):
            found[key] = dict(re.findall(r'(\w+): "([^"]*)"', body))
        else:
            found[key] = {"other": body.strip('"')}
    return found


def _page_wording(check: dict, templates: dict[str, dict[str, str]]) -> str:
    """The check's message as the page words it from `text` (frontend/src/warnings.ts)."""
    figures = dict(check["text"]["figures"])
    segment = figures.get("segment")
    figures["where"] = templates["segment"]["other"].replace("{n}", segment) if segment else ""
    if check["text"]["key"] == "timeOffset.matched":
        refined = figures["refined"]
        figures["how"] = templates[f"offsetSource.{figures['source']}"]["other"] + (
            templates[f"offsetRefined.{refined}"]["other"] if refined else ""
        )
    forms = templates[check["text"]["key"]]
    form = forms["one"] if figures.get("dropped") == "1" and "one" in forms else forms["other"]
    return re.sub(r"\{(\w+)\}", lambda m: figures[m.group(1)], form)


def test_the_pages_english_words_of_every_check_are_the_servers_message():
    """Every check carries a catalogue key and figures (`text`) from which a page in another
    language words it; the English catalogue's template, filled in, is the server's own
    message, so the figures are complete and a translator works from the right text."""

    def photos(outliers: int) -> list[dict]:
        return [{"status": "outlier" if i < outliers else "used"} for i in range(10)]

    shaped = segment()
    shaped["fit"]["shape_sigma"] = {"scale": 0.0017, "rotation_deg": 0.1, "at_edge_m": 0.071}
    dropped = "segment 1 left out: only 3 camera positions fall within the time span"
    rtk_off = {"stated": RTK_SIGMA, "within": False}
    matched = {"ambiguous_reason": None, "prior_source": "srt", "method": "trajectory_fit"}
    unsure = {"ambiguous_reason": "two peaks 4.0 s apart", "prior_source": "log_start"}

    def agree(metres: float) -> dict:
        return {"agreement_m": metres, "cells": 5000, "points_used": 10**5}

    surveys = [
        stages(segment(stated=RTK_SIGMA, within=True)),
        stages(segment(0), segment(1, fit_residuals=(0.2, 0.0, 0.0), **rtk_off)),
        stages(segment(fit_residuals=(0.01, 0.0, 0.4), **rtk_off)),
        stages(segment(fit_residuals=(0.01, 0.0, 0.01), **rtk_off)),
        stages(segment(after=(3.0, 4.0)), dsm={"overlap_coverage": 0.8}),
        stages(segment(0), segment(1, after=(3.0, 4.01)), dsm={"overlap_coverage": 0.79}),
        stages(segment(0), warnings=[dropped]),
        stages(segment(0), warnings=[dropped, dropped.replace("segment 1", "segment 2")]),
        stages(segment(), georeference={"photos": photos(2)}),
        stages(segment(), georeference={"photos": photos(3)}),
        stages(shaped, dsm={"dsm": {"resolution_m": 0.02}}),
        stages(shaped, dsm={"dsm": {"resolution_m": 0.05}}),
        stages(segment(), georeference={"time_offset": matched}),
        stages(segment(), georeference={"time_offset": unsure}),
        stages(segment(), dsm={"dsm": {"resolution_m": 0.05}, "height_agreement": agree(0.1)}),
        stages(segment(), dsm={"dsm": {"resolution_m": 0.05}, "height_agreement": agree(0.3)}),
    ]
    templates = _english_templates()
    keys = set()
    for survey in surveys:
        for check in survey_quality(survey)["checks"]:
            keys.add(check["text"]["key"])
            assert _page_wording(check, templates) == check["message"], check["text"]
    # Every message of the catalogue is made by some check above (the others are parts).
    parts = {"segment"} | {
        k for k in templates if k.startswith(("offsetSource.", "offsetRefined."))
    }
    assert keys == set(templates) - parts

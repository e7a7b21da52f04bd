"""The reconstruction stages' typed results write the JSON the stages always wrote."""

import json
import math

from worker.pipeline.reconstruction_results import FramesResult, GeoreferenceResult

TIME_OFFSET = {
    "offset_s": 0.25,
    "prior_s": 0.25,
    "prior_source": "user",
    "method": "user",
    "score": None,
    "observable": True,
    "warnings": [],
}


def test_keys_written_only_in_some_cases_are_left_out_while_none():
    result = FramesResult(method="sfm", time_offset=TIME_OFFSET, note="as they are", seconds=1.0)
    assert list(result.to_dict()) == ["method", "time_offset", "note", "seconds"]


def test_nan_and_infinity_are_written_as_null():
    result = GeoreferenceResult(
        time_offset={**TIME_OFFSET, "score": math.nan},
        crs="EPSG:32654",
        segments=[{"segment": 0, "residuals_after_m": {"rms_up": math.inf}}],
        time_offset_s=math.nan,
        seconds=1.0,
        warnings=[],
    )
    data = result.to_dict()
    json.dumps(data, allow_nan=False)
    assert data["time_offset_s"] is None and data["time_offset"]["score"] is None
    assert data["segments"][0]["residuals_after_m"]["rms_up"] is None


def test_a_stored_result_reads_back_and_unknown_keys_are_ignored():
    stored = {"method": "slam", "time_offset": TIME_OFFSET, "seconds": 2.0, "newer": 1}
    result = FramesResult.from_dict(stored)
    assert result.time_offset["offset_s"] == 0.25 and result.stills is None
    assert result.to_dict() == {k: v for k, v in stored.items() if k != "newer"}

"""compare_dsms and run_stage: layout, UTM path, idempotency, atomicity, options."""

import itertools
import json
import shutil

import numpy as np
import pytest
import rasterio

from worker.pipeline import raster_io
from worker.pipeline.comparison import (
    ComparisonContext,
    ComparisonOptions,
    compare_dsms,
    comparison_pipeline,
    run_stage,
    stages_for,
    summarize,
)
from worker.pipeline.errors import InputError, PipelineError
from worker.simulator.dsm_pair import make_dsm_pair, write_dsm_pair

STAGES = stages_for("threshold")

LAYOUT = {
    "align": ["pre_aligned.tif", "post_aligned.tif"],
    "coregister": ["post_coregistered.tif", "stable_mask.tif"],
    "difference": ["dh.tif", "significance.tif", "lod.tif", "error_model.json"],
    "vectorize": ["detections.geojson"],
}
ALL_FILES = [name for names in LAYOUT.values() for name in names]


def test_stage_order_and_layout(slide_run):
    assert STAGES == ("align", "coregister", "difference", "vectorize")
    work = slide_run.result.work_dir
    assert sorted(p.name for p in work.iterdir()) == sorted(ALL_FILES)
    assert list(slide_run.result.results) == list(STAGES)
    json.dumps(slide_run.result.results)


def test_summary(slide_run):
    summary = slide_run.result.summary()
    assert summary["detections"] == 1
    assert summary["total_area_m2"] == pytest.approx(slide_run.pair.truth.area_m2, rel=0.05)
    # The shift reported is the correction applied to post.
    assert summary["shift_m"]["east"] == pytest.approx(-2.4, abs=0.1)
    assert summary["shift_m"]["north"] == pytest.approx(1.3, abs=0.1)
    assert summary["shift_m"]["up"] == pytest.approx(-0.5, abs=0.02)
    assert abs(summary["rotation_deg"]) < 0.01  # the pair is not rotated
    assert summarize({}) == {
        "detections": 0,
        "total_area_m2": 0.0,
        "shift_m": {"east": 0.0, "north": 0.0, "up": 0.0},
        "rotation_deg": 0.0,
    }


def test_geographic_input_is_compared_in_utm(geographic_run):
    results = geographic_run.result.results
    assert results["align"]["crs"] == "EPSG:32632"
    assert results["vectorize"]["crs"] == "EPSG:32632"
    collection = json.loads(geographic_run.result.detections_path.read_text())
    assert collection["metric_crs"] == "EPSG:32632"
    assert len(collection["features"]) == 1
    props = collection["features"][0]["properties"]
    truth = geographic_run.pair.truth
    assert abs(props["area_m2"] / truth.area_m2 - 1) < 0.05
    assert abs(props["volume_loss_m3"] / truth.volume_loss_m3 - 1) < 0.10
    assert abs(props["volume_gain_m3"] / truth.volume_gain_m3 - 1) < 0.10
    coreg = results["coregister"]
    assert abs(coreg["shift_east_m"] + 1.2) < 0.1 and abs(coreg["shift_north_m"] + 0.8) < 0.1


def test_each_stage_is_idempotent(slide_run, tmp_path):
    work = tmp_path / "work"
    shutil.copytree(slide_run.result.work_dir, work)
    before = {name: (work / name).read_bytes() for name in ALL_FILES}
    for stage in STAGES:
        result = run_stage(
            stage, slide_run.paths.pre, slide_run.paths.post, work, ComparisonOptions()
        )
        expected = {k: v for k, v in slide_run.result.results[stage].items() if k != "seconds"}
        assert {k: v for k, v in result.items() if k != "seconds"} == expected
        for name in LAYOUT[stage]:
            assert (work / name).read_bytes() == before[name], f"{stage} changed {name}"


def test_run_stage_needs_the_earlier_stages(slide_run, tmp_path):
    with pytest.raises(PipelineError, match="run the earlier stages first"):
        run_stage("difference", slide_run.paths.pre, slide_run.paths.post, tmp_path, None)
    with pytest.raises(InputError, match="'warp' is not a stage of the comparison"):
        run_stage("warp", slide_run.paths.pre, slide_run.paths.post, tmp_path, None)


class _FailingWriter:
    """Wraps a dataset opened for writing; write() writes then fails like a full disk."""

    def __init__(self, dataset):
        self._dataset = dataset

    def __enter__(self):
        self._dataset.__enter__()
        return self

    def __exit__(self, *exc):
        return self._dataset.__exit__(*exc)

    def write(self, *args, **kwargs):
        self._dataset.write(*args, **kwargs)
        raise OSError("No space left on device")

    def __getattr__(self, name):
        return getattr(self._dataset, name)


def test_a_failing_stage_leaves_no_partial_output(slide_run, tmp_path, monkeypatch):
    work = tmp_path / "work"
    shutil.copytree(slide_run.result.work_dir, work)
    (work / "dh.tif").unlink()
    significance_before = (work / "significance.tif").read_bytes()
    real_open = rasterio.open

    def failing_open(path, mode="r", *args, **kwargs):
        dataset = real_open(path, mode, *args, **kwargs)
        return _FailingWriter(dataset) if mode == "w" else dataset

    monkeypatch.setattr(raster_io.rasterio, "open", failing_open)
    with pytest.raises(OSError, match="No space left"):
        run_stage("difference", slide_run.paths.pre, slide_run.paths.post, work, None)
    assert not (work / "dh.tif").exists()
    assert (work / "significance.tif").read_bytes() == significance_before
    assert [p.name for p in work.iterdir() if ".part" in p.name] == []


def test_failing_align_writes_nothing(tmp_path):
    a = make_dsm_pair((100, 100), slide=False, seed=1)
    b = make_dsm_pair((100, 100), slide=False, seed=1, origin=(700000.0, 5100000.0))
    raster_io.write_geotiff(tmp_path / "a.tif", a.pre, a.transform, "EPSG:32632")
    raster_io.write_geotiff(tmp_path / "b.tif", b.pre, b.transform, "EPSG:32632")
    with pytest.raises(InputError, match="do not overlap"):
        compare_dsms(tmp_path / "a.tif", tmp_path / "b.tif", tmp_path / "work")
    assert list((tmp_path / "work").iterdir()) == []


def test_options_round_trip_through_json():
    options = ComparisonOptions()
    options.detection.min_area_m2 = 40.0
    options.difference.lod_m = 0.3
    options.coregister.tilt = False
    data = json.loads(json.dumps(options.to_dict()))
    assert ComparisonOptions.from_dict(data) == options
    partial = ComparisonOptions.from_dict({"vectorize": {"min_area_m2": 10.0}})
    assert partial.detection.min_area_m2 == 10.0 and partial.coregister.tilt is True
    assert ComparisonOptions.from_dict(None) == ComparisonOptions()
    with pytest.raises(InputError, match="unknown vectorize options: min_aera_m2"):
        ComparisonOptions.from_dict({"vectorize": {"min_aera_m2": 10.0}})
    with pytest.raises(InputError, match="unknown comparison options: speed"):
        ComparisonOptions.from_dict({"speed": 1})


def test_progress_is_monotonic_and_ends_at_one(tmp_path):
    pair = make_dsm_pair((200, 200), 1.0, (0.7, 0.2, 0.1), slide=False, seed=21)
    paths = write_dsm_pair(pair, tmp_path / "in")
    seen: list[float] = []
    compare_dsms(paths.pre, paths.post, tmp_path / "work", progress=seen.append)
    assert seen[-1] == 1.0
    assert all(b >= a for a, b in itertools.pairwise(seen))
    assert np.all((np.array(seen) >= 0) & (np.array(seen) <= 1))


def test_stage_results_are_typed_and_read_back_from_json(slide_run, tmp_path):
    """What a job stores of each stage (JSON) reads back as the stage's typed result."""
    work = tmp_path / "work"
    shutil.copytree(slide_run.result.work_dir, work)
    context = ComparisonContext(
        slide_run.paths.pre, slide_run.paths.post, work, ComparisonOptions()
    )
    for spec in comparison_pipeline("threshold").stages:
        result = spec.run(context, lambda _fraction: None)
        stored = json.loads(json.dumps(result.to_dict()))
        again = type(result).from_dict({**stored, "written_by_a_newer_version": 1})
        assert again == result, spec.name
    assert again.detections == slide_run.result.results["vectorize"]["detections"] == 1

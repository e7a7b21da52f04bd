"""`detect` command through click's CliRunner."""

import json

import pytest
from click.testing import CliRunner

from worker.commands.detect import detect
from worker.pipeline.comparison import ComparisonOptions
from worker.pipeline.errors import InputError


def test_detect_writes_geojson_and_prints_one_summary_line(slide_run, tmp_path):
    out = tmp_path / "out" / "detections.geojson"
    work = tmp_path / "work"
    runner = CliRunner()
    result = runner.invoke(
        detect,
        [
            "--pre",
            str(slide_run.paths.pre),
            "--post",
            str(slide_run.paths.post),
            "--out",
            str(out),
            "--work-dir",
            str(work),
            "--min-area",
            "30",
            "--method",
            "threshold",
        ],
    )
    assert result.exit_code == 0, result.output
    lines = result.stdout.strip().splitlines()
    assert len(lines) == 1
    summary = json.loads(lines[0])
    assert summary["detections"] == 1
    assert set(summary) == {"detections", "total_area_m2", "shift_m", "rotation_deg"}
    assert set(summary["shift_m"]) == {"east", "north", "up"}
    assert json.loads(out.read_text())["type"] == "FeatureCollection"
    assert (work / "dh.tif").exists()


def test_fixed_lod_and_temporary_work_dir(slide_run, tmp_path, monkeypatch):
    monkeypatch.setenv("TMPDIR", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", None)
    out = tmp_path / "d.geojson"
    result = CliRunner().invoke(
        detect,
        [
            "--pre",
            str(slide_run.paths.pre),
            "--post",
            str(slide_run.paths.post),
            "--out",
            str(out),
            "--lod",
            "5",
            "--method",
            "threshold",
        ],
    )
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["detections"] == 0  # nothing moved by more than 5 m
    assert list((tmp_path / "tmp").iterdir()) == []  # the temporary work dir is gone


def test_bad_input_exits_2_with_a_plain_message(tmp_path):
    bad = tmp_path / "pre.tif"
    bad.write_text("not a raster")
    out = tmp_path / "out.geojson"
    result = CliRunner().invoke(detect, ["--pre", str(bad), "--post", str(bad), "--out", str(out)])
    assert result.exit_code == 2
    assert "pre.tif is not a GeoTIFF, nor any raster file" in result.stderr
    assert result.stdout == ""
    assert not out.exists()


def test_mown_grass_is_set_aside_only_by_the_lod_method(slide_run, tmp_path):
    """`--vegetation-cut` on the slide pair (bare ground: nothing to set aside) keeps the
    slide; a method without the option refuses it before any work."""
    common = ["--pre", str(slide_run.paths.pre), "--post", str(slide_run.paths.post)]
    out = tmp_path / "threshold.geojson"
    result = CliRunner().invoke(
        detect, [*common, "--out", str(out), "--method", "threshold", "--vegetation-cut"]
    )
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["detections"] == 1
    refused = tmp_path / "cnn.geojson"
    result = CliRunner().invoke(
        detect, [*common, "--out", str(refused), "--method", "cnn", "--vegetation-cut"]
    )
    assert result.exit_code == 2
    assert "--vegetation-cut: the cnn method does not set aside mown grass" in result.stderr
    assert not refused.exists()
    # The API's parameters give the same answer for the scored method.
    with pytest.raises(InputError, match="scored method does not set aside mown grass"):
        ComparisonOptions.from_dict({"method": "scored", "score": {"vegetation_cut": True}})

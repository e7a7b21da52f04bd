"""`slidewatch bench photos` on both GNSS models: the fitted one and the held-out one."""

from __future__ import annotations

import json

from click.testing import CliRunner

from worker.commands.bench_photos import photos as bench_photos

FIGURES = {"median", "p90", "worst"}


def test_bench_photos_reports_the_fitted_and_the_held_out_model(tmp_path):
    out = tmp_path / "photos.json"
    result = CliRunner().invoke(bench_photos, ["--json", str(out), "--seeds", "5"])
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    models = data["models"]
    assert set(models) == {"consumer", "field"}
    assert models["consumer"]["label"].startswith("fitted")
    assert models["field"]["label"].startswith("held out")
    assert "held out" in result.output and "fitted" in result.output
    for block in models.values():
        assert len(block["runs"]) == 5
        for fit in ("robust", "similarity"):
            for key in (
                "horizontal_rms_m",
                "vertical_rms_m",
                "horizontal_rms_beyond_bias_m",
                "residual_horizontal_rms_m",
                "seconds_per_set",
            ):
                assert set(block[fit][key]) == FIGURES
        outliers = block["robust"]["outliers"]
        assert {"planted", "recall", "false_flags", "flagged_moderate"} <= set(outliers)
    # The file's earlier keys repeat the first model's figures.
    assert data["robust"] == models["consumer"]["robust"]
    assert len(data["runs"]) == 5

    field = models["field"]
    robust, plain = field["robust"], field["similarity"]
    # Held out: every planted outlier found, and the residuals of the photos kept within
    # the 3 m in every set.
    assert field["robust"]["outliers"]["recall"] == 1.0
    assert robust["residual_horizontal_rms_m"]["worst"] < 3.0
    # Horizontally the robust fit is level with the similarity (whose RANSAC drops gross
    # fixes too; the flight's mean GNSS error dominates both), not behind it; vertically,
    # beyond that mean, it does not tilt with the barometric walk as the similarity does.
    assert (
        robust["horizontal_rms_beyond_bias_m"]["median"]
        <= plain["horizontal_rms_beyond_bias_m"]["median"]
    )
    assert robust["horizontal_rms_m"]["median"] <= plain["horizontal_rms_m"]["median"] + 0.05
    assert (
        robust["vertical_rms_beyond_bias_m"]["median"]
        < 0.5 * plain["vertical_rms_beyond_bias_m"]["median"]
    )


def test_bench_photos_runs_one_model_alone(tmp_path):
    out = tmp_path / "photos.json"
    result = CliRunner().invoke(
        bench_photos, ["--json", str(out), "--seeds", "2", "--gnss-model", "field"]
    )
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    assert set(data["models"]) == {"field"} and data["gnss"]["mode"] == "field"

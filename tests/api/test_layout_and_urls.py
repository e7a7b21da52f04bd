"""The storage layout and the API's paths, each spelled in one module, and a worker app
that reads its settings only when Celery needs them."""

import os
import subprocess
import sys
from pathlib import Path

from backend import storage_layout as layout
from backend.urls import API_PREFIX, api_url

ROOT = Path(__file__).resolve().parents[2]


def test_storage_layout_keeps_the_paths_already_in_databases() -> None:
    # StoredFile rows keep these paths: a change here would orphan every stored file.
    assert layout.site_surveys_folder(3) == "surveys/3"
    assert layout.survey_folder(3, 7) == "surveys/3/7"
    assert layout.survey_files_folder(3, 7) == "surveys/3/7/files"
    assert layout.survey_reconstruction_file(3, 7, "a.tif") == "surveys/3/7/reconstruction/a.tif"
    assert layout.comparison_folder(5) == "comparisons/5"
    assert layout.comparison_file(5, "cells.geojson") == "comparisons/5/cells.geojson"
    assert layout.comparison_cog_file(5, "dh.tif") == "comparisons/5/cog/dh.tif"
    assert layout.site_uploads_folder(3) == "uploads/3"
    assert layout.upload_part_file(3, 11) == "uploads/3/11.part"
    assert layout.report_file(3, 2, "report.pdf") == "reports/3/2/report.pdf"
    assert layout.model_run_file("slides", "r1", "slides.pt") == "models/slides/r1/slides.pt"


def test_api_url_joins_its_parts_under_the_prefix() -> None:
    assert api_url() == API_PREFIX == "/api/v1"
    assert api_url("sites", 3, "surveys") == "/api/v1/sites/3/surveys"
    assert api_url("sites", 3, "comparisons/4", "wmts") == "/api/v1/sites/3/comparisons/4/wmts"


def test_worker_app_reads_the_settings_when_configured_not_at_import() -> None:
    script = (
        "import worker.celery_app as c, worker.tasks, worker.tasks_monitoring\n"
        "assert not c.app.configured\n"
        "try:\n"
        "    c.app.conf.broker_url\n"
        "except Exception as exc:\n"
        "    print('refused:', type(exc).__name__)\n"
    )
    env = {**os.environ, "SLIDEWATCH_API_PORT": "not-a-port"}
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=ROOT, env=env, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    assert "refused: ValidationError" in done.stdout

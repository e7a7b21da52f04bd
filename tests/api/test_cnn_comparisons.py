"""The cnn method over the API: chosen by name, its products, its detections' model version,
and the model registry (GET /models)."""

from pathlib import Path

import pytest
import rasterio
from fastapi.testclient import TestClient
from rio_cogeo.cogeo import cog_validate

from tests.api_helpers import request_comparison, run_job_inline, upload_dsm
from tests.cnn.conftest import mound_pair

# Co-registration on 50 k pixels: the same result on these small pairs, quicker.
QUICK = {"coregister": {"subsample": 50_000}}


@pytest.fixture(scope="module")
def mound_files(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A sand mound at 2 cm/pixel before and after a slide on its flank."""
    return mound_pair(True, 3).write(tmp_path_factory.mktemp("mound"))


def test_models_lists_the_shipped_default(client: TestClient, auth: dict) -> None:
    listed = client.get("/api/v1/models", headers=auth).json()
    assert len(listed) == 1
    model = listed[0]
    assert model["name"] == "slidenet-default" and model["is_default"]
    assert model["location"] == "package" and model["kind"] == "slidenet"
    assert model["reference"] == f"slidenet-default@{model['version']}"
    assert model["interim"] is False  # trained on reconstructed DSMs
    assert model["card"]["data"]["dsm_source"].startswith("slidewatch reconstruction")
    assert 0 < model["card"]["decision"]["pixel_threshold"] < 1
    assert client.get("/api/v1/models", headers=auth).json() == listed  # registered once


def test_cnn_comparison_stores_probability_cells_and_model_version(
    client: TestClient, auth: dict, mound_files: tuple[Path, Path], tmp_path: Path
) -> None:
    site = client.post("/api/v1/sites", json={"name": "mounds"}, headers=auth).json()["id"]
    pre = upload_dsm(client, auth, site, mound_files[0], "2026-06-01T10:00:00Z")
    post = upload_dsm(client, auth, site, mound_files[1], "2026-07-01T10:00:00Z")
    created = request_comparison(
        client, auth, site, pre["id"], post["id"], "cnn", parameters=QUICK
    ).json()
    assert created["comparison"]["method"] == "cnn"
    # The model is known from the start: the registry's default, kept in the parameters.
    queued = created["comparison"]
    assert queued["detection"]["model"] == queued["parameters"]["cnn"]["model"]
    run_job_inline(created["job"]["id"])
    cid = created["comparison"]["id"]
    comparison = client.get(f"/api/v1/sites/{site}/comparisons/{cid}", headers=auth).json()
    assert comparison["status"] == "succeeded", comparison
    reference = comparison["parameters"]["cnn"]["model"]
    assert comparison["summary"]["stages"]["detect"]["model"] == reference
    detection = comparison["detection"]
    assert detection["method"] == "cnn" and detection["model"] == reference
    assert detection["lod_m"] == comparison["summary"]["stages"]["difference"]["lod_m"] > 0

    features = client.get(
        f"/api/v1/sites/{site}/comparisons/{cid}/detections", headers=auth
    ).json()["features"]
    assert len(features) == 1
    props = features[0]["properties"]
    assert props["method"] == "cnn" and props["model_version"] == reference
    assert props["area_m2"] > 5 and props["volume_loss_m3"] > 0.5 and 0.7 <= props["score"] <= 1
    assert props["uncertainty"] is None  # the cnn method gives no intervals

    products = client.get(f"/api/v1/sites/{site}/comparisons/{cid}/products", headers=auth).json()
    kinds = {p["kind"]: p for p in products}
    assert set(kinds) == {
        "post_coregistered", "dh", "significance", "lod", "probability", "cells", "detections",
    }  # fmt: skip
    probability = kinds["probability"]
    assert probability["file"]["media_type"].endswith("profile=cloud-optimized")
    assert probability["crs"] == "EPSG:32654"
    path = tmp_path / "probability.tif"
    path.write_bytes(client.get(probability["download_url"], headers=auth).content)
    assert cog_validate(str(path), quiet=True)[0]
    with rasterio.open(path) as src:
        assert src.overviews(1) == [2, 4]
        full = src.read(1, masked=True)
        overview = src.read(1, masked=True, out_shape=(300, 300))
    # Averaged, not sampled: the overview keeps the full raster's mean probability.
    assert float(overview.mean()) == pytest.approx(float(full.mean()), abs=0.01)
    cells = client.get(f"/api/v1/sites/{site}/comparisons/{cid}/cells", headers=auth).json()
    assert len(cells["features"]) == comparison["summary"]["stages"]["detect"]["positive_cells"]
    assert all(c["properties"]["fraction"] > 0.1 for c in cells["features"])

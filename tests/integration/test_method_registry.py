"""A detection method declared in one module and registered in one place is everywhere.

The toy method (tests/plugins/toy_method.py) is named in the setting
SLIDEWATCH_DETECTION_METHOD_MODULES, as a user's own method would be; nothing else in the
project knows it. The CLI offers and runs it, the API lists it with its stages, and a
comparison job runs it in a real worker process, its detections stored and served.
"""

import json
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from click.testing import CliRunner

from backend.cli import main
from backend.config import Settings
from tests.integration.conftest import api_client, upload_dsm_pair, wait_for_job
from worker.pipeline.detection_methods import method_names, unregister_method
from worker.simulator.dsm_pair import DsmPairPaths, make_dsm_pair, write_dsm_pair

pytestmark = pytest.mark.integration
TOY_MODULE = "tests.plugins.toy_method"


@pytest.fixture
def toy_registered() -> Iterator[list[str]]:
    """The setting's value; afterwards this process forgets the toy again."""
    assert "toy" not in method_names()
    yield [TOY_MODULE]
    unregister_method("toy")
    sys.modules.pop(TOY_MODULE, None)


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory) -> DsmPairPaths:
    dsm_pair = make_dsm_pair(shape=(300, 300), pixel_size_m=0.5, shift_m=(0.4, 0.2, 0.1), seed=5)
    return write_dsm_pair(dsm_pair, tmp_path_factory.mktemp("pair"))


def test_the_cli_offers_and_runs_a_registered_method(
    toy_registered: list[str], pair: DsmPairPaths, tmp_path: Path
) -> None:
    env = {"SLIDEWATCH_DETECTION_METHOD_MODULES": json.dumps(toy_registered)}
    help_text = CliRunner().invoke(main, ["detect", "--help"], env=env).output
    assert "toy" in help_text
    out = tmp_path / "toy.geojson"
    args = ["detect", "--pre", str(pair.pre), "--post", str(pair.post), "--out", str(out)]
    result = CliRunner().invoke(main, [*args, "--method", "toy"], env=env)
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["detections"] == 1
    feature = json.loads(out.read_text())["features"][0]
    assert feature["id"] == 1 and feature["properties"]["method"] == "toy"


def test_the_api_and_a_worker_run_a_registered_method(
    toy_registered: list[str],
    pair: DsmPairPaths,
    redis_postgres_settings: Settings,
    start_worker,
) -> None:
    settings = redis_postgres_settings.model_copy(
        update={"detection_method_modules": toy_registered}
    )
    start_worker(settings, beat=False)
    client, auth = api_client(settings)
    methods = {m["name"]: m for m in client.get("/api/v1/methods", headers=auth).json()}
    assert methods["toy"]["stages"] == ["align", "coregister", "difference", "box"]
    assert methods["toy"]["summary"].startswith("A toy") and not methods["toy"]["default"]

    site, surveys = upload_dsm_pair(client, auth, pair.pre, pair.post, "toy")
    created = client.post(
        f"/api/v1/sites/{site}/comparisons",
        json={
            "pre_survey_id": surveys[0],
            "post_survey_id": surveys[1],
            "method": "toy",
            "parameters": {"toy": {"height_m": 1.0}},
        },
        headers=auth,
    )
    assert created.status_code == 202, created.text
    job = wait_for_job(
        client, auth, site, created.json()["job"]["id"], lambda j: j["state"] == "failed"
        or j["state"] == "succeeded",
    )  # fmt: skip
    assert job["state"] == "succeeded", job
    box = job["stages"][-1]
    assert (box["stage"], box["help"]) == ("box", "change above a height, boxed")
    comparison = job["comparison_id"]
    served = client.get(
        f"/api/v1/sites/{site}/comparisons/{comparison}/detections", headers=auth
    ).json()["features"]
    assert [f["properties"]["method"] for f in served] == ["toy"]
    # The product file is written from the stored rows: same ids, same fields.
    products = client.get(
        f"/api/v1/sites/{site}/comparisons/{comparison}/products", headers=auth
    ).json()
    detections = next(p for p in products if p["kind"] == "detections")
    stored = client.get(detections["download_url"], headers=auth).json()["features"]
    assert [f["id"] for f in stored] == [f["id"] for f in served]
    assert set(stored[0]["properties"]) == set(served[0]["properties"]) - {"feedback"}

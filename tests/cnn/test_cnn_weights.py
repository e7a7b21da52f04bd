"""The shipped weights: they load, match their card, and do their job on small pairs."""

import json

import numpy as np
import rasterio

from worker.pipeline.cnn.models import SlideNet
from worker.pipeline.cnn.registry import (
    PACKAGE_WEIGHTS,
    default_model_path,
    list_models,
    load_default_model,
)
from worker.pipeline.comparison import default_method
from worker.training.evaluation import rasterize_detections


def test_shipped_weights_load_with_their_card():
    card_path = default_model_path()
    assert card_path is not None
    loaded = load_default_model()
    assert isinstance(loaded.model, SlideNet) and not loaded.model.training
    card = loaded.card
    assert (PACKAGE_WEIGHTS / card.weights_file).stat().st_size < 2_000_000
    # Trained on slidewatch's reconstructions of simulated flights, with the paper's
    # test region held out; the noise-model pairs are named as augmentation.
    assert card.interim is False and card.data["interim"] is False
    assert card.data["dsm_source"].startswith("slidewatch reconstruction of the simulated")
    assert card.data["augmentation_parts"] and not card.data["interim_parts"]
    assert card.training["exclude"]["region"] == "mound-A"
    assert 0 < card.decision["min_score"] < 1 and card.decision["min_score_calibration"]
    assert 0 < card.decision["pixel_threshold"] < 1
    assert [c.name for c in list_models(PACKAGE_WEIGHTS)] == [card.name]
    # Shipped weights no longer make cnn the default: scored is, once its scorer ships.
    assert default_method() in ("scored", "threshold")


def test_finds_the_planted_slide(cnn_slide_run):
    collection = json.loads(cnn_slide_run.result.detections_path.read_text())
    assert len(collection["features"]) == 1
    props = collection["features"][0]["properties"]
    assert props["method"] == "cnn" and props["model_version"].startswith("slidenet-default@")
    with rasterio.open(cnn_slide_run.result.work_dir / "pre_aligned.tif") as src:
        found = rasterize_detections(
            cnn_slide_run.result.detections_path, src.shape, src.transform, src.crs
        )
    truth = cnn_slide_run.pair.mask
    iou = (found & truth).sum() / (found | truth).sum()
    assert iou > 0.6
    assert props["volume_loss_m3"] > 0.5 * cnn_slide_run.pair.volume_loss_m3


def test_nothing_in_a_no_change_pair(cnn_still_run):
    summary = cnn_still_run.result.summary()
    assert summary["detections"] == 0
    with rasterio.open(cnn_still_run.result.work_dir / "probability.tif") as src:
        prob = src.read(1, masked=True)
    assert float(np.ma.max(prob)) < 0.9

"""Short training runs: a small separable set is learnt; runs are deterministic and resume."""

import json

import numpy as np
import pytest
import torch

from tests.cnn.conftest import write_separable_dataset
from worker.pipeline.cnn.registry import load_model
from worker.training.dataset import load_manifest
from worker.training.dense_training import DenseTrainingOptions, train_slidenet
from worker.training.paper_training import PatchTrainingOptions, patch_dataset, train_patchnet
from worker.training.training import Exclusion, load_training_pairs

SMALL = {"filters": (8, 16, 16, 16, 8), "fc": (32, 32)}  # the paper's layout, fewer filters


@pytest.fixture(scope="module")
def separable(tmp_path_factory):
    return load_manifest(write_separable_dataset(tmp_path_factory.mktemp("separable")))


def test_patch_dataset_is_balanced_and_excludes_the_test_region(separable):
    pairs = load_training_pairs(separable, Exclusion("p1", "top", margin_px=42))
    assert np.isnan(pairs[1].pre[:162]).all() and np.isfinite(pairs[1].pre[162:]).all()
    data = patch_dataset(pairs, seed=0)
    assert (data.labels == 1).sum() == (data.labels == 0).sum() > 10
    second = data.group == data.groups.index("p1")
    assert (data.rows[second] >= 162).all()  # no window touches the held-out rows


def test_paper_protocol_learns_a_separable_set_deterministically(separable, tmp_path):
    options = PatchTrainingOptions(
        mode="loose", epochs=4, learning_rate=1e-3, seed=0, max_per_class=64, **SMALL
    )
    first = train_patchnet(separable, tmp_path / "a", "m", options)
    assert first.card.metrics["validation"]["accuracy"] >= 0.85
    assert first.card.training["max_per_class"] == 64 and first.card.interim
    again = train_patchnet(separable, tmp_path / "b", "m", options)
    a = load_model(first.card_path).model.state_dict()
    b = load_model(again.card_path).model.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    metrics = json.loads((tmp_path / "a" / "metrics.json").read_text())
    assert [h["epoch"] for h in metrics["history"]] == [1, 2, 3, 4]


def test_training_resumes_from_the_last_checkpoint(separable, tmp_path):
    options = PatchTrainingOptions(
        mode="fixed", epochs=2, learning_rate=1e-3, seed=1, max_per_class=32, **SMALL
    )
    straight = train_patchnet(separable, tmp_path / "straight", "m", options)
    options.epochs = 1
    train_patchnet(separable, tmp_path / "resumed", "m", options)
    options.epochs = 2
    resumed = train_patchnet(separable, tmp_path / "resumed", "m", options)
    assert resumed.resumed_from_epoch == 1
    a = load_model(straight.card_path).model.state_dict()
    b = load_model(resumed.card_path).model.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_dense_training_learns_the_pits(separable, tmp_path):
    options = DenseTrainingOptions(
        epochs=3,
        steps_per_epoch=12,
        batch_size=4,
        tile_px=64,
        validate_every=3,
        block_px=120,
        scales=(1,),
    )
    result = train_slidenet(separable, tmp_path / "dense", "d", options)
    validation = result.card.metrics["validation"]
    assert validation["best_f1"] >= 0.8
    assert result.card.decision["pixel_threshold"] in options.thresholds


def test_train_command(separable, tmp_path):
    from click.testing import CliRunner

    from worker.commands.train import train

    args = ["--dataset", str(separable.path), "--out", str(tmp_path), "--epochs", "1"]
    result = CliRunner().invoke(
        train, [*args, "--model", "patchnet-fixed", "--max-per-class", "16", "--threads", "1"]
    )
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    assert summary["model"].startswith("patchnet-fixed@") and summary["interim_data"]
    card = json.loads((tmp_path / "patchnet-fixed" / "patchnet-fixed.json").read_text())
    assert card["training"]["exclude"] == {"pair": "p1", "region": "top", "margin_px": 42}
    missing = CliRunner().invoke(train, ["--out", str(tmp_path)])
    assert missing.exit_code == 2 and "--dataset" in missing.stderr

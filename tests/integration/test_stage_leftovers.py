"""The temporaries of a killed stage are known by name and removed before it runs again."""

import os
import tempfile
from pathlib import Path

from worker.jobs.leftovers import is_leftover, job_folder, remove_leftovers
from worker.pipeline.atomic import atomic_path


def test_the_names_are_those_the_writers_give(tmp_path: Path) -> None:
    with atomic_path(tmp_path / "dh.tif") as part, atomic_path(tmp_path / "summary") as plain:
        assert is_leftover(part.name) and is_leftover(plain.name)
    with tempfile.TemporaryDirectory(dir=tmp_path) as folder:
        assert is_leftover(Path(folder).name)
    with tempfile.TemporaryDirectory(dir=tmp_path, prefix=".dsm-") as folder:
        assert is_leftover(Path(folder).name)
    for kept in ("dh.tif", "detections.geojson", "cog", "frames", "tmp", ".dsm-", "x.part"):
        assert not is_leftover(kept)


def test_leftovers_are_removed_and_nothing_else(tmp_path: Path) -> None:
    kept = [tmp_path / "dh.tif", tmp_path / "cog" / "dh.tif"]
    left = [
        tmp_path / "tmpab12_xyz" / "probability.tif",
        tmp_path / "cog" / ".dh.tif.k3j_9zq1.part.tif",
        tmp_path / ".dsm-0a1b2c3d" / "dsm.tif",
    ]
    for path in kept + left:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("x")
    elsewhere = tmp_path.parent / f"{tmp_path.name}-outside"
    (elsewhere / "tmpzzzzzzzz").mkdir(parents=True)
    os.symlink(elsewhere, tmp_path / "inputs")  # links are not followed

    removed = remove_leftovers(tmp_path)
    assert sorted(removed) == sorted(
        [tmp_path / "tmpab12_xyz", tmp_path / "cog" / left[1].name, tmp_path / ".dsm-0a1b2c3d"]
    )
    assert all(p.exists() for p in kept) and not any(p.exists() for p in left)
    assert (elsewhere / "tmpzzzzzzzz").is_dir()


def test_the_job_folder_is_named_by_the_inputs(tmp_path: Path) -> None:
    assert job_folder({"work_dir": str(tmp_path)}) == tmp_path
    assert job_folder({"out_dir": str(tmp_path)}) == tmp_path
    assert job_folder({"rejected": "no data"}) is None
    assert remove_leftovers(None) == [] and remove_leftovers(tmp_path / "missing") == []

"""SfM refines the focal length only when the intrinsics are a guess."""

import pycolmap
import pytest

from worker.pipeline.ingest.camera import resolve_intrinsics
from worker.pipeline.sfm import SfmOptions, _mapping_options, _refined


def test_known_camera_keeps_its_focal_length_fixed():
    intr = resolve_intrinsics(320, 180, exif_model="FC6310")
    mapping = _mapping_options(SfmOptions(), intr.focal_guess)
    assert not mapping.ba_refine_focal_length
    assert not mapping.mapper.abs_pose_refine_focal_length
    assert not mapping.ba_refine_principal_point and not mapping.ba_refine_extra_params


def test_guessed_focal_length_is_refined_and_used():
    intr = resolve_intrinsics(320, 180)
    assert intr.focal_guess
    mapping = _mapping_options(SfmOptions(), intr.focal_guess)
    assert mapping.ba_refine_focal_length
    assert mapping.mapper.abs_pose_refine_focal_length
    # Only the focal length: the principal point and distortion stay as they are.
    assert not mapping.ba_refine_principal_point and not mapping.ba_refine_extra_params
    rec = pycolmap.Reconstruction()
    rec.add_camera(
        pycolmap.Camera(
            model="SIMPLE_PINHOLE", width=320, height=180, params=[250.0, 159.5, 89.5], camera_id=1
        )
    )
    refined = _refined(intr, rec)
    assert (refined.fx, refined.fy) == pytest.approx((250.0, 250.0))
    assert (refined.cx, refined.cy) == (intr.cx, intr.cy)
    assert (
        "SfM refined the guessed focal length from fx = 213 px to 250 px" in (refined.warnings[-1])
    )
    assert len(intr.warnings) == 1  # the input is left as it was

"""SfM keeps the focal length fixed, a guessed one too unless asked to refine it."""

import pycolmap
import pytest

from worker.pipeline.ingest.camera import resolve_intrinsics
from worker.pipeline.sfm import SfmOptions, _mapping_options, _refined, refines_focal


def test_known_camera_keeps_its_focal_length_fixed():
    intr = resolve_intrinsics(320, 180, exif_model="FC6310")
    assert not intr.focal_guess
    assert not refines_focal(intr, SfmOptions())
    assert not refines_focal(intr, SfmOptions(refine_guessed_focal=True))
    mapping = _mapping_options(SfmOptions(), refine_focal=False)
    assert not mapping.ba_refine_focal_length
    assert not mapping.mapper.abs_pose_refine_focal_length
    assert not mapping.ba_refine_principal_point and not mapping.ba_refine_extra_params


def test_a_guessed_focal_length_is_kept_unless_refining_is_asked_for():
    intr = resolve_intrinsics(320, 180)
    assert intr.focal_guess
    assert not refines_focal(intr, SfmOptions())  # a drone survey cannot tell it
    assert refines_focal(intr, SfmOptions(refine_guessed_focal=True))
    mapping = _mapping_options(SfmOptions(), refine_focal=True)
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

"""A part of a flight that hardly moves, or only climbs, is left out with its reason while
the part that moved is georeferenced; a climb counts as motion where the log's camera
attitude fixes the heading (worker/pipeline/georef.py `_check_motion`, georef_map.py)."""

import re

import numpy as np
import pytest
from pyproj import Transformer

from worker.pipeline.attitude import rotation_world_from_camera
from worker.pipeline.errors import InputError
from worker.pipeline.georef import GeoreferenceError
from worker.pipeline.georef_map import MapGeorefOptions, georeference_map
from worker.pipeline.ingest.flight_log import build_flight_log
from worker.pipeline.quality import survey_quality
from worker.pipeline.slam.result import SparseMap

EPSG = 32633
ORIGIN = np.array([500_000.0, 5_200_000.0, 300.0])
K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 180.0], [0.0, 0.0, 1.0]])
CLIMB_S = 4.0


def _true_path(t: np.ndarray) -> np.ndarray:
    """The paper's 3-D path in short: 4 s climbing from 5 to 13 m in place, then 3 m/s
    east."""
    climb = np.clip(t, 0.0, CLIMB_S)
    east = 3.0 * np.clip(t - CLIMB_S, 0.0, None)
    return np.column_stack([east, np.zeros(t.size), 5.0 + 2.0 * climb]) + ORIGIN


def _log(attitude: bool, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 12.0, 0.1)
    pos = _true_path(t) + rng.normal(0, 0.02, (t.size, 3))
    lon, lat = Transformer.from_crs(f"EPSG:{EPSG}", "EPSG:4326", always_xy=True).transform(
        pos[:, 0], pos[:, 1]
    )
    rows = []
    for i in range(t.size):
        row = {"line": i + 2, "t": float(t[i]), "lat": lat[i], "lon": lon[i], "alt": pos[i, 2]}
        if attitude:
            row.update(gimbal_yaw=90.0, gimbal_pitch=-90.0, gimbal_roll=0.0)
        rows.append(row)
    return build_flight_log("flight.csv", "generic_csv", rows)


def _map(segments: list[np.ndarray], seed: int = 1) -> SparseMap:
    """Keyframes at the times of each segment, in a local frame (turned a quarter, half
    the scale), a nadir camera heading east; points 5 m below each camera."""
    rng = np.random.default_rng(seed)
    turn = rotation_world_from_camera(90.0, 0.0, 0.0)
    times = np.concatenate(segments)
    seg = np.concatenate([np.full(t.size, k, np.int32) for k, t in enumerate(segments)])
    centres = 0.5 * (_true_path(times) - ORIGIN + rng.normal(0, 0.01, (times.size, 3))) @ turn.T
    world_from_cam = rotation_world_from_camera(np.full(times.size, 90.0), -90.0, 0.0 * times)
    r = np.einsum("ij,njk->nik", turn, world_from_cam).transpose(0, 2, 1)
    return SparseMap.from_keyframes(
        K,
        (640, 360),
        t=times,
        r=r,
        tr=-np.einsum("nij,nj->ni", r, centres),
        segment=seg,
        obs_kf=np.zeros(0),
        obs_point=np.zeros(0),
        obs_uv=np.zeros((0, 2)),
        point_id=np.arange(times.size),
        point_xyz=centres - 0.5 * (np.array([0.0, 0.0, 5.0]) @ turn.T),
        point_segment=seg,
    )


CLIMB = np.arange(0.2, 3.5, 0.25)  # climbing in place: 6.6 m up, no horizontal motion
HOVER = np.arange(0.0, 0.6, 0.1)  # the first half second: 1 m up
ACROSS = np.arange(5.0, 11.5, 0.25)  # flying east


def _georeference(segments, attitude: bool):
    return georeference_map(_map(segments), _log(attitude), 0.0, MapGeorefOptions(refine=False))


def test_a_part_that_only_climbs_is_left_out_without_attitude_and_the_rest_placed():
    result = _georeference([CLIMB, ACROSS], attitude=False)
    assert [s["segment"] for s in result.segments] == [1]
    (reason,) = [w for w in result.warnings if w.startswith("segment 0 left out")]
    assert re.search(r"moved only 0\.\d m horizontally during 0\.2-3\.5 s of the video", reason)
    assert re.search(r"climbing or descending 6\.\d m", reason)
    assert "no camera attitude" in reason
    after = result.segments[0]["residuals_after_m"]
    assert np.hypot(after["rms_east"], after["rms_north"]) < 0.05
    # The verdict names the part left out.
    quality = survey_quality({"georeference": result.to_dict()})
    (check,) = [c for c in quality["checks"] if c["name"] == "segments_dropped"]
    assert check["value"] == 1 and "1 of 2 flight segments" in check["message"]


def test_a_climb_with_the_camera_attitude_is_georeferenced():
    result = _georeference([CLIMB, ACROSS], attitude=True)
    assert [s["segment"] for s in result.segments] == [0, 1]
    climb = result.segments[0]
    assert climb["fit"]["attitude_used"]
    after = climb["residuals_after_m"]
    assert np.hypot(after["rms_east"], after["rms_north"]) < 0.05 and after["rms_up"] < 0.05
    assert climb["fit"]["similarity"]["scale"] == pytest.approx(2.0, rel=0.02)


@pytest.mark.parametrize("attitude", [False, True])
def test_a_part_that_hardly_moves_is_left_out_and_alone_it_fails_saying_why(attitude):
    result = _georeference([HOVER, ACROSS], attitude=attitude)
    assert [s["segment"] for s in result.segments] == [1]
    pattern = r"^segment 0 left out: the aircraft moved only 0\.\d m horizontally and 1\.\d m "
    assert any(re.match(pattern, w) for w in result.warnings)
    with pytest.raises(GeoreferenceError, match=r"during 0\.0-0\.5 s of the video"):
        _georeference([HOVER], attitude=attitude)
    with pytest.raises(InputError, match="no part of the reconstruction could be georeferenced"):
        _georeference([HOVER, HOVER + 0.05], attitude=attitude)

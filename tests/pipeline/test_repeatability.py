"""repeatability: the paper's Table 1 figure (mean pairwise checkpoint difference) and
checkpoints moved by the co-registration of a survey onto a reference survey."""

import numpy as np
import pytest
from rasterio.transform import Affine

from worker.pipeline.errors import InputError
from worker.pipeline.raster_io import write_geotiff
from worker.pipeline.repeatability import coregister_checkpoints, mean_pairwise_difference
from worker.simulator.dsm_pair import make_dsm_pair


def test_mean_pairwise_difference_averages_every_pair_and_checkpoint():
    first = np.array([[0.0, 0.0, 0.0], [10.0, 5.0, 2.0]])
    second = first + np.array([1.0, 2.0, 3.0])
    third = first + np.array([-1.0, 0.0, 3.0])
    # pairs: |1-2| = (1, 2, 3), |1-3| = (1, 0, 3), |2-3| = (2, 2, 0)
    assert mean_pairwise_difference([first, second, third]) == pytest.approx([4 / 3, 4 / 3, 2.0])
    assert mean_pairwise_difference([first, first]) == pytest.approx([0.0, 0.0, 0.0])


def test_mean_pairwise_difference_rejects_unusable_input():
    with pytest.raises(InputError, match="two surveys"):
        mean_pairwise_difference([np.zeros((3, 3))])
    with pytest.raises(InputError, match="same"):
        mean_pairwise_difference([np.zeros((3, 3)), np.zeros((2, 3))])


def test_checkpoints_of_a_shifted_survey_on_another_grid_land_on_the_reference(tmp_path):
    shift, tilt = (1.8, 2.6, -0.9), (-2.0, 1.0)
    pair = make_dsm_pair((300, 300), 1.0, shift, slide=False, seed=11, tilt_m_per_km=tilt)
    crs = "EPSG:32632"
    write_geotiff(tmp_path / "reference.tif", pair.pre, pair.transform, crs)
    # The later survey covers a different extent: its grid starts 20 rows, 12 columns in.
    survey_transform = pair.transform * Affine.translation(12, 20)
    write_geotiff(tmp_path / "survey.tif", pair.post[20:, 12:], survey_transform, crs)

    rows, cols = np.array([60, 150, 240]), np.array([70, 160, 250])
    x, y = pair.transform * (cols + 0.5, rows + 0.5)
    on_reference = np.column_stack([x, y, pair.pre[rows, cols]])
    centre_x, centre_y = pair.transform * (150, 150)
    moved_x, moved_y = x + shift[0], y + shift[1]
    raise_m = shift[2] + (tilt[0] * (moved_x - centre_x) + tilt[1] * (moved_y - centre_y)) / 1000
    on_survey = np.column_stack([moved_x, moved_y, on_reference[:, 2] + raise_m])

    moved, result = coregister_checkpoints(
        tmp_path / "reference.tif", tmp_path / "survey.tif", on_survey
    )
    after = mean_pairwise_difference([on_reference, moved])
    assert after[0] < 0.1 and after[1] < 0.1 and after[2] < 0.03
    assert result.shift_east_m == pytest.approx(-1.8, abs=0.1)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["reference.tif", "survey.tif"]

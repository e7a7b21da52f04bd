"""Rendered frames match reprojections of the truth, with correct occlusion."""

import av
import cv2
import numpy as np
import pytest
import rasterio
from simtest_support import local_grid, short_run

from worker.simulator.camera import (
    CameraModel,
    project_world,
    rotation_from_quaternion,
    rotation_world_from_camera,
)
from worker.simulator.georef import Grid
from worker.simulator.render import HeightFieldRenderer, RenderOptions
from worker.simulator.truth_io import read_trajectory_csv

CAM = CameraModel.phantom4pro(640, 360)
CLEAN = RenderOptions(noise_sigma=0.0, vignetting=0.0)


def _scene():
    """Flat ground at 10 m, a smooth hill, steep cones (trees) and box pillars."""
    grid = Grid.centered(24.0, 24.0, 0.04)
    x, y = grid.mesh()
    z = 10.0 + 1.2 * np.exp(-((x - 1) ** 2 + (y + 3) ** 2) / 8.0)
    rng = np.random.default_rng(2)
    for cx, cy in rng.uniform(-9, 9, (14, 2)):
        r = np.hypot(x - cx, y - cy)
        z = np.where(r < 0.8, np.maximum(z, 10.0 + 3.5 * (1 - r / 0.8) + 1.0), z)
    for cx, cy, hw, h in [(-3.0, 2.0, 0.5, 2.5), (1.5, -6.0, 0.3, 1.8)]:
        box = (np.abs(x - cx) < hw) & (np.abs(y - cy) < hw)
        z = np.where(box, 10.0 + h, z)
    tex = rng.random((grid.height // 8 + 1, grid.width // 8 + 1, 3)) * 200 + 30
    ortho = cv2.resize(
        tex.astype(np.uint8), (grid.width, grid.height), interpolation=cv2.INTER_NEAREST
    )
    return grid, z.astype(np.float32), ortho


def _first_hits(renderer, position, r_wc, pix, step):
    """Brute force: march each ray in tiny steps to its first crossing."""
    rays = renderer._world_rays(r_wc)  # (east, north, up) components
    c_cr, d_cr = renderer._ray_setup(np.asarray(position, float), rays)
    d = np.stack(rays, axis=1)
    taus = np.arange(0.05, 60.0, step, dtype=np.float32)
    out = []
    for p in pix:
        di = tuple(np.full(taus.size, comp[p], np.float32) for comp in d_cr)
        f = renderer._gap(c_cr, di, taus)
        k = int(np.argmax(f <= 0))
        out.append(np.nan if f[k] > 0 else taus[k - 1] + step * f[k - 1] / (f[k - 1] - f[k]))
    return np.array(out), np.linalg.norm(d[pix], axis=1)


@pytest.mark.parametrize("pitch", [-90.0, -55.0])
def test_occlusion_matches_brute_force_ray_marching(pitch):
    grid, dsm, ortho = _scene()
    r = HeightFieldRenderer(dsm, grid, ortho, CAM, CLEAN)
    position = np.array([-1.0, -1.0, 18.0])
    r_wc = rotation_world_from_camera(30.0, pitch, 2.0)
    frame = r.render(position, r_wc, with_geometry=True)
    pix = np.random.default_rng(1).integers(0, CAM.width * CAM.height, 1500)
    truth, dnorm = _first_hits(r, position, r_wc, pix, step=0.004)
    rendered = frame.depth.ravel()[pix]
    ok = np.isfinite(truth)
    assert ok.mean() > 0.99
    err_m = np.abs(rendered[ok] - truth[ok]) * dnorm[ok]
    # The first surface along the ray, exactly, except at silhouettes of steep objects
    # (a ray clipping a wall by less than a cell): a wrong surface (> 10 cm away along
    # the ray) in fewer than 0.5 % of the pixels, a centimetre-level slip in < 3 %.
    assert np.median(err_m) < 1e-3
    assert np.mean(err_m > 0.1) < 0.005
    assert np.mean(err_m > 0.02) < 0.03


def test_projected_markers_land_on_the_pixels_that_show_them():
    grid, dsm, ortho = _scene()
    ortho = (ortho * 0.5).astype(np.uint8)  # no saturated red in the background
    markers = {"flat": (-6.0, -4.0), "hill": (1.6, -2.4), "behind_pillar": (-3.0, 3.2)}
    for mx, my in markers.values():
        rows, cols = grid.window(mx - 0.1, my - 0.1, mx + 0.1, my + 0.1)
        ortho[rows, cols] = (255, 0, 0)
    r = HeightFieldRenderer(dsm, grid, ortho, CAM, CLEAN)
    # Looking north at 50 deg down, from the south: the 2.5 m pillar at (-3, 2) hides
    # the marker 1.2 m behind it.
    position = np.array([-3.0, -9.0, 17.0])
    r_wc = rotation_world_from_camera(0.0, -50.0, 0.0)
    img = r.render(position, r_wc).image
    red = (img[..., 0] > 180) & (img[..., 1] < 60) & (img[..., 2] < 60)
    _, _, _, centroids = cv2.connectedComponentsWithStats(red.astype(np.uint8))
    for name, (mx, my) in markers.items():
        col, row = grid.col_row(mx, my)
        mz = dsm[round(float(row)), round(float(col))]
        uv, depth = project_world(CAM, position, r_wc, np.array([[mx, my, mz]]))
        u, v = uv[0]
        assert depth[0] > 0 and 0 <= u < CAM.width and 0 <= v < CAM.height, name
        if name == "behind_pillar":
            near = red[max(0, int(v) - 6) : int(v) + 7, max(0, int(u) - 6) : int(u) + 7]
            assert not near.any(), "an occluded marker is visible"
            continue
        dist = np.hypot(centroids[1:, 0] - u, centroids[1:, 1] - v)
        assert dist.min() < 1.0, (name, dist.min())


def test_video_frames_match_a_reprojection_of_the_written_truth():
    run = short_run()
    survey = run.survey(1)
    grid = local_grid(run)
    with rasterio.open(run.truth(1, "dsm")) as src:
        dsm = src.read(1)
    with rasterio.open(run.truth(1, "ortho")) as src:
        ortho = np.moveaxis(src.read(), 0, -1)
    cam = CameraModel.from_dict(run.data["camera"])
    traj = read_trajectory_csv(run.root / survey["trajectory"])
    origin = np.array([run.data["frame"]["origin_e"], run.data["frame"]["origin_n"], 0.0])
    opts = RenderOptions(**{**run.data["options"]["render"], "noise_sigma": 0.0})
    renderer = HeightFieldRenderer(dsm, grid, ortho, cam, opts)
    with av.open(str(run.root / survey["video"])) as container:
        decoded = {}
        for i, fr in enumerate(container.decode(video=0)):
            if i in (0, 45, 89):
                decoded[i] = fr.to_ndarray(format="rgb24")
            if i > 89:
                break
    assert set(decoded) == {0, 45, 89}
    for i, img in decoded.items():
        pos = np.array([traj["e"][i], traj["n"][i], traj["u"][i]]) - origin
        rot = rotation_from_quaternion([traj[k][i] for k in ("qw", "qx", "qy", "qz")])
        again = renderer.render(pos, rot).image
        # Same picture up to sensor noise and H.264; one pixel off would show.
        mse = np.mean((again.astype(np.float64) - img) ** 2)
        psnr = 10 * np.log10(255.0**2 / mse)
        assert psnr > 32.0, (i, psnr)
        for axis in (0, 1):
            shifted = np.roll(again, 1, axis=axis)
            assert mse < 0.5 * np.mean((shifted.astype(np.float64) - img) ** 2)


def test_render_rate_is_recorded():
    rendering = short_run().data["rendering"]
    assert rendering["frames"] == sum(s["surveys"][0]["frames"] for s in short_run().steps)
    assert 0 < rendering["cpu_ms_per_frame"] < 200
    for step in short_run().steps:  # completed after the background render and encode
        survey = step["surveys"][0]
        assert survey["video_codec"] in ("libx264", "mpeg4")
        assert 0 < survey["render"]["cpu_ms_per_frame"] < 200
        assert survey["render"]["frames_per_second_wall_incl_encoding"] > 0

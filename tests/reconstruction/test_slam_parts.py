"""SLAM building blocks: tracking, bundle adjustment, SGBM densification, the map,
point-cloud filters and the frames stage, on synthetic data with known geometry."""

import cv2
import numpy as np
import pytest

from worker.pipeline.frames import (
    BlurFilter,
    FrameOptions,
    KeyframePolicy,
    iter_prepared_frames,
    prepare_video_frames,
    read_frame_scan,
    sharpness,
    tracking_frames,
)
from worker.pipeline.pointcloud import grid_outliers, read_ply, statistical_outliers, write_ply
from worker.pipeline.slam.bundle import BAProblem, bundle_adjust
from worker.pipeline.slam.densify import densify_pair
from worker.pipeline.slam.geometry import triangulate_midpoint
from worker.pipeline.slam.result import SparseMap
from worker.pipeline.slam.tracker import KltTracker
from worker.simulator.camera import CameraModel, rotation_world_from_camera
from worker.simulator.georef import Grid
from worker.simulator.render import HeightFieldRenderer, RenderOptions

K = np.array([[427.0, 0.0, 319.5], [0.0, 427.0, 179.5], [0.0, 0.0, 1.0]])


def texture(shape: tuple[int, int], seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    h, w = shape
    img = np.zeros((h, w), np.float32)
    for step, amp in ((32, 0.5), (8, 0.3), (2, 0.2)):
        small = rng.random((h // step + 2, w // step + 2)).astype(np.float32)
        img += amp * cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)[:h, :w]
    return cv2.normalize(img, None, 20, 235, cv2.NORM_MINMAX).astype(np.uint8)


@pytest.fixture(scope="module")
def terrain():
    """A 120 m textured height field and a renderer looking down at it."""
    grid = Grid.centered(120.0, 120.0, 0.1)
    x, y = grid.mesh()
    dsm = (50 + 3 * np.sin(x / 9.0) * np.cos(y / 11.0) + 0.05 * x).astype(np.float32)
    ortho = np.repeat(texture(grid.shape, 1)[..., None], 3, axis=2)
    camera = CameraModel.phantom4pro(640, 360)
    renderer = HeightFieldRenderer(
        dsm, grid, ortho, camera, RenderOptions(noise_sigma=0.5, vignetting=0.0)
    )
    return grid, dsm, renderer


def render_gray(renderer, centre, heading=0.0):
    r = rotation_world_from_camera(heading, -90.0, 0.0)
    frame = renderer.render(np.asarray(centre, float), r)
    return cv2.cvtColor(frame.image, cv2.COLOR_RGB2GRAY), r


def test_klt_tracks_keep_their_ids():
    base = texture((400, 700), 2)
    tracker = KltTracker()
    first = base[20:380, 30:670]
    tracker.track(first)
    assert tracker.detect(first) > 300
    ids0, pts0 = tracker.ids.copy(), tracker.pts.copy()
    ids1, pts1 = tracker.track(base[24:384, 27:667])  # content moves by (-3, -4) px
    common, i0, i1 = np.intersect1d(ids0, ids1, return_indices=True)
    assert len(common) > 0.9 * len(ids0)
    np.testing.assert_allclose(np.median(pts1[i1] - pts0[i0], axis=0), [3.0, -4.0], atol=0.05)
    tracker.remove(common[:10])
    assert not np.isin(common[:10], tracker.ids).any()


def test_midpoint_triangulation():
    x = np.array([[1.0, 2.0, 3.0], [-4.0, 0.5, 7.0]])
    c1, c2 = np.zeros((2, 3)), np.tile([1.0, 0.0, 0.0], (2, 1))
    d1 = x / np.linalg.norm(x, axis=1, keepdims=True)
    d2 = (x - c2) / np.linalg.norm(x - c2, axis=1, keepdims=True)
    p, s, u, angle = triangulate_midpoint(c1, d1, c2, d2)
    np.testing.assert_allclose(p, x, atol=1e-9)
    assert (s > 0).all() and (u > 0).all() and (angle > 0).all()


def _ba_scene(seed: int = 0, n_cam: int = 12, n_pts: int = 800):
    rng = np.random.default_rng(seed)
    r_cw = rotation_world_from_camera(0.0, -90.0, 0.0).T
    centres = np.column_stack(
        [np.arange(n_cam) * 4.0, 8 * np.sin(np.arange(n_cam) / 2.0), np.full(n_cam, 60.0)]
    )
    pts = np.column_stack(
        [rng.uniform(-30, 75, n_pts), rng.uniform(-40, 40, n_pts), rng.normal(0, 2, n_pts)]
    )
    obs = {}
    for i, c in enumerate(centres):
        pc = (pts - c) @ r_cw.T
        uv = pc[:, :2] / pc[:, 2:] * 427.0 + [319.5, 179.5]
        vis = np.flatnonzero((uv[:, 0] > 0) & (uv[:, 0] < 640) & (uv[:, 1] > 0) & (uv[:, 1] < 360))
        obs[i] = (vis.astype(np.int64), uv[vis] + rng.normal(0, 0.3, (vis.size, 2)))
    return rng, r_cw, centres, pts, obs


def test_windowed_bundle_adjustment_with_fixed_frames():
    rng, r_cw, centres, pts, obs = _ba_scene()
    poses = {
        i: (r_cw, -r_cw @ (c + (rng.normal(0, 0.4, 3) if i >= 4 else 0)))
        for i, c in enumerate(centres)
    }
    noisy = {j: pts[j] + rng.normal(0, 0.4, 3) for j in range(len(pts))}
    new_poses, _, report = bundle_adjust(
        BAProblem(poses, obs, noisy, fixed={0, 1, 2, 3}), K, (640, 360), max_iterations=30
    )
    err = [np.linalg.norm(-r.T @ t - centres[i]) for i, (r, t) in new_poses.items()]
    assert max(err[:4]) < 1e-9  # fixed
    assert max(err) < 0.1
    assert report.final_cost < report.initial_cost and report.points > 500


def test_bundle_adjustment_leaves_out_points_seen_once():
    _, r_cw, centres, pts, obs = _ba_scene(2, n_cam=6, n_pts=300)
    poses = {i: (r_cw, -r_cw @ c) for i, c in enumerate(centres)}
    # Keyframe 5 alone sees points 1000..1019; point 0 is left out of the problem.
    ids5, uv5 = obs[5]
    obs[5] = (np.concatenate([ids5, np.arange(1000, 1020)]), np.vstack([uv5, uv5[:20]]))
    points = {j: pts[j] for j in range(1, len(pts))}
    points.update({j: pts[0] for j in range(1000, 1020)})
    seen = np.concatenate([ids for ids, _ in obs.values()])
    ids, counts = np.unique(seen[np.isin(seen, list(points))], return_counts=True)
    _, new_points, report = bundle_adjust(
        BAProblem(poses, obs, points, fixed={0, 1}), K, (640, 360), max_iterations=3
    )
    assert sorted(new_points) == ids[counts >= 2].tolist()
    assert report.points == 166 and report.points == len(new_points)
    assert report.observations == counts[counts >= 2].sum() == 866
    assert report.keyframes == 6


def test_pose_priors_move_the_model_onto_gnss():
    rng, r_cw, centres, pts, obs = _ba_scene(1)
    shift = np.array([3.0, -2.0, 1.0])
    poses = {i: (r_cw, -r_cw @ (c + shift)) for i, c in enumerate(centres)}
    moved = {j: pts[j] + shift for j in range(len(pts))}
    priors = {
        i: (c + rng.normal(0, 0.05, 3), np.array([0.05, 0.05, 0.1])) for i, c in enumerate(centres)
    }
    new_poses, _, report = bundle_adjust(BAProblem(poses, obs, moved, priors=priors), K, (640, 360))
    assert report.priors_used == len(centres)
    err = [np.linalg.norm(-r.T @ t - centres[i]) for i, (r, t) in new_poses.items()]
    assert np.median(err) < 0.1


def _seen(grid: Grid, dsm: np.ndarray, centre: np.ndarray, r_cw: np.ndarray) -> np.ndarray:
    """Points of the surface a camera sees, in its frame (what the sparse map gives)."""
    x, y = grid.mesh()
    world = np.column_stack([x[::40, ::40].ravel(), y[::40, ::40].ravel(), dsm[::40, ::40].ravel()])
    cam = (world - centre) @ r_cw.T
    u = K[0, 0] * cam[:, 0] / cam[:, 2] + K[0, 2]
    v = K[1, 1] * cam[:, 1] / cam[:, 2] + K[1, 2]
    return cam[(cam[:, 2] > 0) & (u >= 0) & (u < 640) & (v >= 0) & (v < 360)]


@pytest.mark.parametrize(
    ("heading", "heading_b", "move", "bias_m"),
    [
        (0.0, 0.0, (0.0, 6.0, 0.0), 0.07),  # along the image's vertical axis
        (90.0, 90.0, (6.0, 0.0, 0.0), 0.07),
        (0.0, 0.0, (0.0, -6.0, 0.0), 0.07),  # the second camera behind the first
        # Climbing and descending at 45 degrees: the views, tilted by as much, are drawn
        # at half the focal length, and the two images' ground at scales 8 % apart.
        (0.0, 0.0, (0.0, 5.0, 5.0), 0.12),
        (0.0, 0.0, (0.0, 5.0, -5.0), 0.12),
        (0.0, 25.0, (3.0, 5.0, 0.0), 0.07),  # in a turn
    ],
)
def test_sgbm_densification_recovers_the_surface(terrain, heading, heading_b, move, bias_m):
    grid, dsm, renderer = terrain
    ca = np.array([0.0, 0.0, 110.0])
    cb = ca + move
    ga, r = render_gray(renderer, ca, heading)
    gb, r_b = render_gray(renderer, cb, heading_b)
    r_cw, r_cw_b = r.T, r_b.T
    seen = _seen(grid, dsm, ca, r_cw)
    pts = densify_pair(ga, gb, K, (r_cw, -r_cw @ ca), (r_cw_b, -r_cw_b @ cb), seen)
    # Of the 640 x 360 / 4 = 57 600 pixels sampled, most: the second camera sees most of
    # the first's ground (OpenCV's rectification, cropping to what both keep, gave 29 000
    # on the climb and the descent, 37 000 in the turn).
    assert len(pts) > 40000
    world = pts @ r_cw + ca
    col, row = grid.col_row(world[:, 0], world[:, 1])
    truth = dsm[
        np.clip(np.rint(row).astype(int), 0, grid.height - 1),
        np.clip(np.rint(col).astype(int), 0, grid.width - 1),
    ]
    err = world[:, 2] - truth
    # sigma_Z = Z^2 / (f B) sigma_d = 1.4 m per pixel of disparity here: a bias of a
    # twentieth of a pixel (SGBM's sub-pixel fit leans towards whole pixels; OpenCV's
    # rectification gave 0.04-0.05 m level and 0.10 m on the descent), the noise 0.3 px
    # or better.
    assert abs(np.median(err)) < bias_m
    assert 1.4826 * np.median(np.abs(err - np.median(err))) < 0.4


def _tiny_map() -> SparseMap:
    r = np.stack([rotation_world_from_camera(0.0, -90.0, 0.0).T] * 3)
    centres = np.array([[0.0, 0.0, 10.0], [1.0, 0.0, 10.0], [2.0, 0.0, 10.0]])
    tr = -np.einsum("nij,nj->ni", r, centres)
    eye = np.broadcast_to(np.eye(3), (3, 3, 3)).copy()
    return SparseMap(
        k=K,
        size=(640, 360),
        kf_id=np.arange(3, dtype=np.int32),
        kf_segment=np.zeros(3, np.int32),
        kf_t=np.array([0.0, 1.0, 2.0]),
        kf_r=r,
        kf_tr=tr,
        obs_kf=np.zeros(0, np.int32),
        obs_point=np.zeros(0, np.int64),
        obs_uv=np.zeros((0, 2), np.float32),
        point_id=np.array([7], np.int64),
        point_xyz=np.array([[1.0, 1.0, 0.0]]),
        point_segment=np.zeros(1, np.int32),
        fr_t=np.array([0.0, 1.0, 2.0]),
        fr_segment=np.zeros(3, np.int32),
        fr_r=r.copy(),
        fr_tr=tr.copy(),
        fr_is_kf=np.ones(3, bool),
        fr_ref_kf=np.arange(3, dtype=np.int32),
        fr_rel_r=eye,
        fr_rel_t=np.zeros((3, 3)),
        dense_kf=np.array([0, 0], np.int32),
        dense_partner=np.array([2, 2], np.int32),
        dense_xyz=np.array([[0.0, 0.0, 10.0], [1.0, -1.0, 9.0]], np.float32),
        dense_baseline=np.array([2.0, 2.0]),
    )


def test_map_transform_moves_everything_consistently(tmp_path):
    m = _tiny_map()
    before = m.dense_points()
    np.testing.assert_allclose(before[0], [0.0, 0.0, 0.0], atol=1e-9)
    rot = rotation_world_from_camera(30.0, 0.0, 0.0)[:, [0, 2, 1]]
    rot = np.linalg.qr(rot)[0] * np.sign(np.linalg.det(np.linalg.qr(rot)[0]))
    s, t = 2.5, np.array([100.0, 200.0, 5.0])
    m.transform(s, rot, t)
    np.testing.assert_allclose(m.dense_points(), s * before @ rot.T + t, atol=1e-9)
    np.testing.assert_allclose(m.point_xyz, s * np.array([[1.0, 1.0, 0.0]]) @ rot.T + t)
    np.testing.assert_allclose(m.trajectory().positions, m.kf_centres(), atol=1e-9)
    m.save(tmp_path / "map.npz")
    again = SparseMap.load(tmp_path / "map.npz")
    np.testing.assert_allclose(again.dense_points(), m.dense_points())


def test_grid_outliers_and_statistical_outliers():
    rng = np.random.default_rng(0)
    pts = np.column_stack(
        [rng.uniform(0, 20, 40000), rng.uniform(0, 20, 40000), rng.normal(0, 0.02, 40000)]
    )
    pts[:50, 2] += 3.0
    keep = grid_outliers(pts, 1.0)
    assert not keep[:50].any() and keep[50:].mean() > 0.99
    sparse = pts[::20].copy()
    sparse[:3, 2] += 5.0
    assert not statistical_outliers(sparse)[:3].any()


def test_grid_outliers_in_threads_keep_the_same_points():
    # Above 200k points the cell columns are split into bands filtered in parallel: a
    # band edge must not change which points go.
    rng = np.random.default_rng(1)
    n = 300_000
    pts = np.column_stack([rng.uniform(0, 30, n), rng.uniform(0, 10, n), rng.normal(0, 0.02, n)])
    spikes = rng.choice(n, 300, replace=False)
    pts[spikes, 2] += rng.choice([-1.0, 1.0], 300) * rng.uniform(0.5, 2.0, 300)
    single = grid_outliers(pts, 0.5, threads=1)
    assert (grid_outliers(pts, 0.5, threads=2) == single).all()
    assert (grid_outliers(pts, 0.5, threads=3) == single).all()
    assert not single[spikes].any() and single.sum() > n - 300 - 0.01 * n


def test_ply_round_trip_keeps_utm_precision(tmp_path):
    pts = np.array([[419342.7012, 3990808.0535, 31.9863], [419343.1, 3990809.2, 32.5]])
    write_ply(tmp_path / "p.ply", pts, comment="crs EPSG:32654")
    back, comments = read_ply(tmp_path / "p.ply")
    np.testing.assert_array_equal(back, pts)
    assert comments == ["crs EPSG:32654"]


def test_blur_filter_and_keyframe_policy():
    sharp = texture((360, 640), 4)
    blurred = cv2.GaussianBlur(sharp, (0, 0), 4)
    assert sharpness(blurred) < 0.2 * sharpness(sharp)
    f = BlurFilter(ratio=0.5, window=11)
    decisions = [f.accept(sharpness(sharp)) for _ in range(8)] + [f.accept(sharpness(blurred))]
    assert all(decisions[:8]) and not decisions[-1]
    policy = KeyframePolicy(parallax_px=30, min_survival=0.7, min_tracked_points=60)
    assert policy.is_keyframe(31, 0.9, 200)
    assert policy.is_keyframe(5, 0.6, 200)
    assert policy.is_keyframe(5, 0.9, 40)
    assert not policy.is_keyframe(5, 0.9, 200)


def write_panning_video(path, blurred_frame: int | None = None) -> None:
    """30 frames at 20 fps of 640 x 360 panning 10 px per frame over a texture; one frame
    blurred if asked."""
    import av

    base = texture((400, 1400), 5)
    container = av.open(str(path), "w")
    stream = container.add_stream("libx264", rate=20)
    stream.width, stream.height, stream.pix_fmt = 640, 360, "yuv420p"
    for i in range(30):
        img = base[20:380, 10 * i : 10 * i + 640]
        if i == blurred_frame:
            img = cv2.GaussianBlur(img, (0, 0), 5)
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="gray")
        for packet in stream.encode(frame):
            container.mux(packet)
    for packet in stream.encode():
        container.mux(packet)
    container.close()


def test_frames_stage_drops_blurred_frames(tmp_path):
    path = tmp_path / "v.mp4"
    write_panning_video(path, blurred_frame=15)
    result = prepare_video_frames(path, tmp_path / "frames", FrameOptions(width=320, height=180))
    assert result.scan.kept.sum() == 29 and not result.scan.kept[15]
    moving = result.scan.motion_px_s[1:]
    assert np.nanmedian(moving) == pytest.approx(10 * 20 / 2, rel=0.1)  # 10 px/frame at half size
    frames = list(iter_prepared_frames(tmp_path / "frames"))
    assert len(frames) == 29 and frames[15].index == 16
    assert frames[0].image.shape == (180, 320)


def test_frames_stage_stores_only_the_tracked_frames(tmp_path):
    path = tmp_path / "v.mp4"
    write_panning_video(path)
    # 5 px per frame at half size: a 12 px step takes every third frame, and the last.
    result = prepare_video_frames(
        path, tmp_path / "frames", FrameOptions(width=320, height=180), track_step_px=12.0
    )
    scan = read_frame_scan(tmp_path / "frames" / "frames.csv")
    stored = scan.index[scan.stored]
    assert stored.tolist() == [0, 3, 6, 9, 12, 15, 18, 21, 24, 27, 29]
    assert stored.tolist() == tracking_frames(scan, 12.0, 0.5).tolist()
    assert result.to_dict()["stored"] == 11 and result.to_dict()["kept"] == 30
    frames = list(iter_prepared_frames(tmp_path / "frames"))
    assert [f.index for f in frames] == stored.tolist()
    np.testing.assert_allclose([f.t for f in frames], stored / 20, atol=1e-6)


def write_colour_video(path, pix_fmt: str = "yuv420p", colour_range: int | None = None) -> None:
    """20 frames at 20 fps of 640 x 360 colour panning 10 px per frame."""
    import av

    grey = texture((400, 1400), 6)
    base = cv2.merge([grey, np.roll(grey, 40, axis=1), 255 - grey])  # B, G, R differ
    container = av.open(str(path), "w")
    stream = container.add_stream("libx264", rate=20)
    stream.width, stream.height, stream.pix_fmt = 640, 360, pix_fmt
    stream.options = {"crf": "10"}
    if colour_range is not None:
        stream.codec_context.color_range = colour_range
    for i in range(20):
        frame = av.VideoFrame.from_ndarray(
            np.ascontiguousarray(base[20:380, 10 * i : 10 * i + 640]), format="bgr24"
        )
        for packet in stream.encode(frame.reformat(format=pix_fmt)):
            container.mux(packet)
    for packet in stream.encode():
        container.mux(packet)
    container.close()


@pytest.mark.parametrize(
    "pix_fmt, colour_range", [("yuv420p", None), ("yuvj420p", 2), ("yuv444p", None)]
)
def test_frames_stage_stores_its_frames_in_colour_for_the_orthophoto(
    tmp_path, pix_fmt, colour_range
):
    """The stored frames, also in colour at the size asked for: the same frames in the
    same order with their original times, their colours those of the video's frames
    (limited- or full-range 4:2:0, or 4:4:4 through FFmpeg's scaler)."""
    from worker.pipeline.ingest.video import iter_frames

    path = tmp_path / "v.mp4"
    write_colour_video(path, pix_fmt, colour_range)
    out = tmp_path / "frames"
    result = prepare_video_frames(
        path, out, FrameOptions(width=320, height=180), track_step_px=12.0, colour_size=(480, 270)
    )
    assert result.colour_size == (480, 270) and result.to_dict()["colour_size"] == (480, 270)
    grey = list(iter_prepared_frames(out))
    colour = list(iter_prepared_frames(out, colour=True))
    assert [f.index for f in grey] == [0, 3, 6, 9, 12, 15, 18, 19]
    assert [f.index for f in colour] == [f.index for f in grey]
    assert [f.t for f in colour] == [f.t for f in grey]
    decoded = {f.index: f.image for f in iter_frames(path, size=(480, 270), gray=False)}

    def smooth(image: np.ndarray) -> np.ndarray:
        # Compared beyond the finest detail, where two resamplings of a texture of 2 px
        # colour grain (and 4:4:4's chroma reduced to 4:2:0) differ by 4-7 grey levels.
        return cv2.GaussianBlur(image.astype(np.float32), (0, 0), 2.0)

    for frame in colour:
        assert frame.image.shape == (270, 480, 3)
        error = np.abs(smooth(frame.image) - smooth(decoded[frame.index])).mean(axis=(0, 1))
        assert (error < 3.0).all(), (frame.index, error)  # grey levels, per channel
    # Only the frames asked for are converted; the others are not yielded.
    wanted = {grey[2].t, grey[5].t}
    some = list(iter_prepared_frames(out, colour=True, wanted=lambda t: t in wanted))
    assert [f.index for f in some] == [grey[2].index, grey[5].index]


def test_frames_stage_without_colour_leaves_no_earlier_colour_copy(tmp_path):
    path = tmp_path / "v.mp4"
    write_colour_video(path)
    out = tmp_path / "frames"
    options = FrameOptions(width=320, height=180)
    prepare_video_frames(path, out, options, colour_size=(640, 360))
    assert (out / "colour.mkv").is_file()
    result = prepare_video_frames(path, out, options)
    assert result.colour_video_path is None and not (out / "colour.mkv").exists()


def test_tracking_loss_starts_a_new_segment(terrain):
    """Fly along x, jump 150 m (nothing in common), fly on: two segments, each a good
    trajectory up to a similarity."""
    from worker.pipeline.georef import umeyama
    from worker.pipeline.ingest.camera import resolve_intrinsics
    from worker.pipeline.slam.system import SlamOptions, run_slam

    grid, dsm, _ = terrain
    ortho = np.repeat(texture(grid.shape, 1)[..., None], 3, axis=2)
    camera = CameraModel.phantom4pro(320, 180)
    renderer = HeightFieldRenderer(dsm, grid, ortho, camera, RenderOptions(noise_sigma=0.5))
    r = rotation_world_from_camera(90.0, -90.0, 0.0)
    centres = [np.array([-45.0 + 1.2 * i, -20.0, 110.0]) for i in range(36)]
    centres += [np.array([-45.0 + 1.2 * i, 25.0, 110.0]) for i in range(36)]
    frames = []
    for i, c in enumerate(centres):
        image = renderer.render(c, r).image
        frames.append((i / 10.0, i, cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)))
    intr = resolve_intrinsics(320, 180, exif_model="FC6310")
    options = SlamOptions(init_parallax_px=12.0, init_min_points=40)
    options.keyframes.parallax_px = 15.0
    options.densify.enabled = False
    sparse = run_slam(frames, intr, options)
    assert sparse.stats["counts"]["lost"] == 1
    assert sparse.segments == [0, 1]
    truth = np.array(centres)
    for segment in sparse.segments:
        traj = sparse.trajectory(segment)
        idx = np.rint(traj.t * 10).astype(int)
        sim = umeyama(traj.positions, truth[idx])
        err = np.linalg.norm(sim.apply(traj.positions) - truth[idx], axis=1)
        assert len(traj) > 20 and err.max() < 0.3


def _straight_line_flight(terrain, readout_s: float = 0.0):
    """Forty 320 x 180 frames looking down from 110 m, 1.2 m apart along a line over the
    test terrain (10 frames a second: 12 m/s), and the SLAM options for them: (camera
    rotation, centres, frames, intrinsics, options). With `readout_s`, the frames are
    read through a rolling shutter of that readout."""
    from worker.pipeline.ingest.camera import resolve_intrinsics
    from worker.pipeline.slam.system import SlamOptions
    from worker.simulator.rolling_shutter import margin_for

    grid, dsm, _ = terrain
    ortho = np.repeat(texture(grid.shape, 1)[..., None], 3, axis=2)
    camera = CameraModel.phantom4pro(320, 180)
    r = rotation_world_from_camera(90.0, -90.0, 0.0)
    centres = np.array([[-30.0 + 1.2 * i, 0.0, 110.0] for i in range(40)])
    half = 0.5 * readout_s * np.array([12.0, 0.0, 0.0])  # the readout's half a move
    turns = np.stack([r] * len(centres))
    margin = margin_for(camera, (centres - half, turns), (centres + half, turns), centres[:, 2])
    render = RenderOptions(noise_sigma=0.5, rolling_shutter_margin_px=margin if readout_s else 0)
    renderer = HeightFieldRenderer(dsm, grid, ortho, camera, render)

    def view(c):
        if not readout_s:
            return renderer.render(c, r).image
        return renderer.render(np.stack([c, c - half, c + half]), np.stack([r, r, r])).image

    frames = [
        (i / 10.0, i, cv2.cvtColor(view(c), cv2.COLOR_RGB2GRAY)) for i, c in enumerate(centres)
    ]
    intr = resolve_intrinsics(320, 180, exif_model="FC6310")
    options = SlamOptions(init_parallax_px=12.0, init_min_points=40)
    options.keyframes.parallax_px = 15.0
    return r, centres, frames, intr, options


def _dense_height_errors(terrain, sparse, r, centres):
    """The straight-line flight's dense heights minus the terrain's, and which dense
    points fell on it: cameras on a straight line leave the roll about it free, so the
    map is put on the ground by the first keyframe's known attitude, its scale and
    offset fitted to the flown centres (within 0.3 m)."""
    grid, dsm, _ = terrain
    traj = sparse.trajectory(0)
    truth = centres[np.rint(traj.t * 10).astype(int)]
    world_from_map = r @ sparse.kf_r[0]
    placed = traj.positions @ world_from_map.T
    d_placed, d_truth = placed - placed.mean(axis=0), truth - truth.mean(axis=0)
    scale = float(np.sum(d_placed * d_truth) / np.sum(d_placed**2))
    offset = truth.mean(axis=0) - scale * placed.mean(axis=0)
    assert np.abs(scale * placed + offset - truth).max() < 0.3
    points = scale * sparse.dense_points() @ world_from_map.T + offset
    col, row = grid.col_row(points[:, 0], points[:, 1])
    col, row = np.rint(col).astype(int), np.rint(row).astype(int)
    inside = (col >= 0) & (col < grid.shape[1]) & (row >= 0) & (row < grid.shape[0])
    return points[inside, 2] - dsm[row[inside], col[inside]], inside


def test_densification_in_the_worker_thread_is_repeatable(terrain):
    """SGBM runs beside the tracking; its inputs are fixed when queued, so two runs give
    the same dense cloud."""
    from worker.pipeline.slam.system import run_slam

    _, _, frames, intr, options = _straight_line_flight(terrain)
    first = run_slam(frames, intr, options)
    second = run_slam(frames, intr, options)
    assert first.stats["counts"]["dense_pairs"] >= 8
    assert first.dense_xyz.shape[0] > 20000
    np.testing.assert_array_equal(first.dense_xyz, second.dense_xyz)
    np.testing.assert_array_equal(first.dense_kf, second.dense_kf)
    assert first.stats["timing_s"]["densify_thread"] > 0


def test_a_wider_second_pair_gives_quieter_heights(terrain):
    """Each keyframe is matched with a partner at a tenth of the depth and with a wider
    one at a fifth: the wider pair's heights, against the terrain's truth, scatter less
    (a height's noise falls as the baseline grows)."""
    from worker.pipeline.slam.system import run_slam

    r, centres, frames, intr, options = _straight_line_flight(terrain)
    sparse = run_slam(frames, intr, options)
    error, inside = _dense_height_errors(terrain, sparse, r, centres)
    is_wide = sparse.dense_wide_pair()[inside]
    ratio = (sparse.dense_baseline / sparse.dense_xyz[:, 2])[inside]
    wide, narrow = error[is_wide], error[~is_wide]
    assert wide.size > 20_000 and narrow.size > 20_000

    def nmad(e):
        return 1.4826 * np.median(np.abs(e - np.median(e)))

    assert nmad(wide) < 0.6 * nmad(narrow)
    assert np.median(ratio[is_wide]) == pytest.approx(0.2, abs=0.04)
    assert np.median(ratio[~is_wide]) == pytest.approx(0.1, abs=0.03)


def test_wide_pairs_refine_narrow_ones_where_both_agree_and_never_stand_alone():
    """A narrow pair over 20 x 20 m (heights 10 cm noisy); a wide one (3 cm) over its
    western half, with a 5-m-wide strip beyond the narrow pair's reach and a block of
    cells 8 m off (mismatches). The DSM keeps the wide pair's points where the two agree,
    the narrow pair's everywhere else, and nothing of the wide pair alone."""
    from worker.pipeline.slam.densify import wide_pair_points

    rng = np.random.default_rng(5)
    narrow = np.column_stack([rng.uniform(0, 20, (2, 40_000)).T, rng.normal(0, 0.10, 40_000)])
    wide = np.column_stack(
        [rng.uniform(-5, 10, 30_000), rng.uniform(0, 20, 30_000), rng.normal(0, 0.03, 30_000)]
    )
    wrong = (wide[:, 0] > 2) & (wide[:, 0] < 4) & (wide[:, 1] > 2) & (wide[:, 1] < 4)
    wide[wrong, 2] += 8.0
    points = np.concatenate([narrow, wide])
    is_wide = np.concatenate([np.zeros(40_000, bool), np.ones(30_000, bool)])
    keep = wide_pair_points(points, is_wide, 0.5)
    kept_wide, kept_narrow = keep[40_000:], keep[:40_000]
    agree = (wide[:, 0] >= 0) & (wide[:, 0] < 9.5) & ~wrong
    assert kept_wide[agree].mean() > 0.99
    assert not kept_wide[wide[:, 0] < 0].any()  # alone beyond the narrow pair's reach
    assert not kept_wide[wrong].any()
    in_wrong = (narrow[:, 0] > 2) & (narrow[:, 0] < 4) & (narrow[:, 1] > 2) & (narrow[:, 1] < 4)
    assert kept_narrow[in_wrong].all()
    assert kept_narrow[narrow[:, 0] >= 10.0].all()
    assert kept_narrow[(narrow[:, 0] > 1) & (narrow[:, 0] < 9) & ~in_wrong].mean() < 0.02
    # Every cell the narrow pair measured keeps a height.
    cells = {tuple(c) for c in np.floor(narrow[:, :2] / 0.5).astype(int)}
    kept_cells = {tuple(c) for c in np.floor(points[keep, :2] / 0.5).astype(int)}
    assert cells <= kept_cells
    west = keep & (points[:, 0] > 0) & (points[:, 0] < 9.5) & (points[:, 2] < 4)
    assert np.std(points[west, 2]) == pytest.approx(0.03, rel=0.15)
    # A point kilometres away (before the footprint filter drops it) changes nothing.
    far = points.copy()
    far[0] += 3000.0
    np.testing.assert_array_equal(wide_pair_points(far, is_wide, 0.5)[1:], keep[1:])
    # Without wide pairs every point stays.
    assert wide_pair_points(narrow, np.zeros(40_000, bool), 0.5).all()


@pytest.mark.parametrize("readout_given", [False, True])
def test_a_rolling_shutter_flight_gives_true_heights_when_its_readout_is_given(
    terrain, readout_given
):
    """The straight-line flight of the SLAM tests (320 x 180 from 110 m at 12 m/s)
    rendered through a 30-ms rolling shutter: its dense heights, placed on the ground by
    the trajectory, sit 0.4 m off the truth when the readout is not given and within
    0.1 m when it is."""
    from dataclasses import replace

    from worker.pipeline.slam.system import run_slam

    r, centres, frames, intr, options = _straight_line_flight(terrain, readout_s=0.03)
    sparse = run_slam(frames, replace(intr, readout_s=0.03 if readout_given else 0.0), options)
    error, _ = _dense_height_errors(terrain, sparse, r, centres)
    assert error.size > 20_000
    if readout_given:
        assert abs(np.median(error)) < 0.1
        assert np.abs(sparse.kf_motion).sum() > 0 and sparse.readout_s == 0.03
    else:
        assert abs(np.median(error)) > 0.3

"""The frame pool: worker processes, shared frame buffers, background jobs."""

import numpy as np
import pytest

from worker.simulator.camera import CameraModel, rotation_world_from_camera
from worker.simulator.frames import FramePool, RenderRun
from worker.simulator.georef import Grid
from worker.simulator.render import RenderOptions

CAM = CameraModel.phantom4pro(160, 90)
OPTS = RenderOptions()


def _scene():
    grid = Grid.centered(12.0, 12.0, 0.04)
    x, y = grid.mesh()
    z = 5.0 + 0.8 * np.exp(-((x - 1) ** 2 + (y + 1) ** 2) / 4.0)
    z = np.where(np.hypot(x + 2, y - 2) < 0.6, z + 1.5, z)  # a steep post
    rng = np.random.default_rng(3)
    ortho = (rng.random((grid.height, grid.width, 3)) * 200 + 30).astype(np.uint8)
    return grid, z.astype(np.float32), ortho


def _poses(n: int):
    t = np.linspace(0.0, 1.0, n)
    pos = np.stack([-3.0 + 6.0 * t, np.zeros(n), np.full(n, 14.0)], axis=1)
    rot = np.stack([rotation_world_from_camera(10.0 * k, -80.0, 0.0) for k in t])
    return pos, rot


def _frames(workers: int, tmp_path, n: int = 17) -> list[np.ndarray]:
    grid, dsm, ortho = _scene()
    pos, rot = _poses(n)
    with FramePool(workers, tmp_path / f"w{workers}", chunk=2, slots=2) as pool:
        ref = pool.scene("a", dsm, grid, ortho, CAM, OPTS, noise_seed=5)
        return pool.submit(ref, pos, rot, list, exposure=1.03).result()


def test_frames_do_not_depend_on_the_number_of_workers(tmp_path):
    one = _frames(1, tmp_path)
    two = _frames(2, tmp_path)
    assert len(one) == len(two) == 17
    for a, b in zip(one, two, strict=True):
        assert a.shape == (CAM.height, CAM.width, 3) and np.array_equal(a, b)


@pytest.mark.parametrize("workers", [1, 2])
def test_a_failing_consumer_leaves_the_pool_usable(tmp_path, workers):
    grid, dsm, ortho = _scene()
    pos, rot = _poses(13)

    def stop_early(frames):
        for i, _ in enumerate(frames):
            if i == 3:
                raise KeyError("consumer failed")

    with FramePool(workers, tmp_path, chunk=2, slots=2) as pool:
        ref = pool.scene("a", dsm, grid, ortho, CAM, OPTS, noise_seed=5)
        failed = pool.submit(ref, pos, rot, stop_early)
        run = RenderRun()
        # Queued behind the failure, other poses: replies of the failed job's chunks
        # still in flight must not be taken for this job's.
        back_pos, back_rot = pos[::-1], rot[::-1]
        later = pool.submit(ref, back_pos, back_rot, list, stats=run)
        with pytest.raises(KeyError):
            failed.result()
        frames = later.result()
        # And a synchronous render after the background jobs.
        again = list(pool.render(ref, back_pos[:4], back_rot[:4]))
    assert run.frames == 13 and run.cpu_seconds > 0
    assert all(np.array_equal(a, b) for a, b in zip(frames[:4], again, strict=True))
    assert not np.array_equal(frames[0], frames[-1])


def test_video_and_image_set_of_one_survey_are_both_counted(tmp_path):
    # Survey 'both': the video renders in the background while the image set renders
    # in the foreground; each keeps its own counters.
    from worker.simulator.simulate import SimulationOptions, simulate_scenario

    opts = SimulationOptions(
        seed=5,
        steps=1,
        survey="both",
        video_seconds=1.0,
        width=160,
        height=90,
        image_width=228,
        image_height=152,
        image_overlap=0.5,
        registration=False,
    )
    m = simulate_scenario("paper-mounds", tmp_path / "run", opts)
    s = m.survey(1)
    assert s["frames"] == 31 and s["images"] > 0
    assert m.data["rendering"]["frames"] == s["frames"] + s["images"]
    assert s["render"]["cpu_ms_per_frame"] > 0
    assert (m.root / s["video"]).stat().st_size > 0 and (m.root / s["preview"]).exists()

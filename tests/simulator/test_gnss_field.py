"""The held-out "field" GNSS error generator (worker/simulator/gnss_field.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from worker.commands.simulate import simulate_command
from worker.simulator.gnss import GnssErrorModel, simulate_gnss
from worker.simulator.gnss_field import (
    FieldGnssModel,
    named_gnss_model,
    simulate_field_gnss,
    simulate_flight_gnss,
)

SPEED = 8.0


def lawnmower(t: np.ndarray) -> np.ndarray:
    """Four 160 m lines 40 m apart at 8 m/s (20 s each, 5 s turns), hovering outside."""
    t = np.clip(np.asarray(t, dtype=np.float64), 0.0, 95.0)
    line, into = np.divmod(t, 25.0)
    along = np.minimum(into, 20.0) * SPEED
    x = np.where(line % 2 == 0, along, 160.0 - along)
    turning = into > 20.0
    y = line * 40.0 + np.where(turning, (into - 20.0) / 5.0 * 40.0, 0.0)
    return np.column_stack([x, y, np.full_like(t, 80.0)])


def draw(seed: int, model: FieldGnssModel | None = None):
    return simulate_field_gnss(
        model or FieldGnssModel(), -5.0, 100.0, lawnmower, np.random.default_rng(seed)
    )


def test_the_same_seed_gives_the_same_errors_and_the_parts_add_up():
    a, b, c = draw(4), draw(4), draw(5)
    np.testing.assert_array_equal(a.error_enu, b.error_enu)
    assert not np.allclose(a.error_enu, c.error_enu)
    np.testing.assert_allclose(sum(a.parts.values()), a.error_enu)
    np.testing.assert_allclose(a.outlier_enu, a.parts["multipath"] + a.parts["slip"])
    times = np.array([1.0, 33.3, 77.7])
    np.testing.assert_allclose(a.error_at(times)[:, 0], np.interp(times, a.t, a.error_enu[:, 0]))


def test_multipath_outliers_cluster_in_space_and_come_as_runs():
    model = replace(FieldGnssModel(), multipath_zones=(1, 1), multipath_jitter_m=0.5)
    for seed in range(10):
        track = draw(seed, model)
        zone = track.zones[0]
        hit = np.linalg.norm(track.parts["multipath"], axis=1) > 0
        pos = lawnmower(track.t)
        dist = np.hypot(*(pos[:, :2] - zone["centre_en_m"]).T)
        # Every affected fix lies in the zone, every fix in the zone is affected.
        np.testing.assert_array_equal(hit, dist <= zone["radius_m"] + 1e-6)
        assert 0 < hit.mean() <= model.multipath_max_share + 0.02
        # Tens of metres, one direction per zone (the reflecting wall's).
        off = track.parts["multipath"][hit, :2]
        size = np.linalg.norm(off, axis=1)
        assert size.max() >= 0.5 * model.multipath_h_m[0]
        mean_dir = zone["offset_enu_m"][:2] / np.linalg.norm(zone["offset_enu_m"][:2])
        assert (off @ mean_dir / size > 0.9).mean() > 0.9
        # Runs of consecutive fixes, not isolated ones: far fewer runs than fixes.
        runs = np.count_nonzero(np.diff(hit.astype(int)) == 1) + int(hit[0])
        assert runs <= hit.sum() / 3
        # Clustered: the affected fixes lie within a zone much smaller than the survey.
        assert np.ptp(pos[hit, 0]) < 0.5 * np.ptp(pos[:, 0])


def test_the_barometric_altitude_walks_with_a_variance_growing_linearly():
    model = replace(
        FieldGnssModel(),
        altitude_ramp_sigma_m_per_s=0.0,
        multipath_zones=(0, 0),
        slip_rate_hz=0.0,
    )
    alt = np.array([draw(seed, model).parts["altitude"][:, 2] for seed in range(300)])
    t = draw(0, model).t - (-5.0)
    var = alt.var(axis=0)
    at = {s: var[np.searchsorted(t, s)] for s in (20.0, 80.0)}
    walk = model.altitude_walk_m_per_sqrt_s
    # Var = walk^2 t within sampling error (300 draws: about +-16 % at 2 sigma).
    for s, v in at.items():
        assert 0.75 * walk**2 * s < v < 1.3 * walk**2 * s
    assert 3.0 < at[80.0] / at[20.0] < 5.3
    # The ramp alone is a straight line in time.
    ramp_only = replace(model, altitude_walk_m_per_sqrt_s=0.0, altitude_ramp_sigma_m_per_s=0.1)
    up = draw(7, ramp_only).parts["altitude"][:, 2]
    np.testing.assert_allclose(np.diff(up, 2), 0.0, atol=1e-9)
    assert abs(up[-1]) > 0.0


def test_time_tag_slips_are_whole_seconds_along_the_track():
    model = replace(FieldGnssModel(), slip_rate_hz=0.1, multipath_zones=(0, 0))
    track = draw(3, model)
    windows = [(s["start_s"], s["end_s"]) for s in track.slips]
    checked = 0
    for slip in track.slips:
        assert slip["slip_s"] in (-2, -1, 1, 2)
        start, end = slip["start_s"], slip["end_s"]
        if any(a < end and start < b for a, b in windows if (a, b) != (start, end)):
            continue  # overlapping slips: the later one wins
        sel = (track.t >= start) & (track.t < end)
        expected = lawnmower(track.t[sel] + slip["slip_s"]) - lawnmower(track.t[sel])
        np.testing.assert_allclose(track.parts["slip"][sel], expected, atol=1e-9)
        checked += 1
    assert checked >= 3
    outside = np.ones(track.t.size, bool)
    for a, b in windows:
        outside &= ~((track.t >= a) & (track.t < b))
    assert not track.parts["slip"][outside].any()
    # On a straight line at 8 m/s a one-second slip is 8 m along the track.
    along = np.hypot(*track.parts["slip"][~outside, :2].T)
    assert (
        np.isclose(along, SPEED, atol=0.01).any() or np.isclose(along, 2 * SPEED, atol=0.01).any()
    )


def test_the_noise_has_heavy_tails():
    model = replace(FieldGnssModel(), multipath_zones=(0, 0), slip_rate_hz=0.0)
    noise = np.concatenate([draw(s, model).parts["noise"][:, 0] for s in range(20)])
    scaled = noise / model.noise_scale_m[0]
    # Student-t with 3 degrees of freedom: P(|x| > 5) = 1.5 %; a Gaussian's is 6e-7.
    assert 0.005 < np.mean(np.abs(scaled) > 5.0) < 0.04


def test_the_simulator_and_its_command_know_both_photo_models():
    choices = next(p for p in simulate_command.params if p.name == "gnss").type.choices
    assert {"consumer", "field"} <= set(choices)
    assert isinstance(named_gnss_model("field"), FieldGnssModel)
    consumer = named_gnss_model("consumer")
    assert consumer == GnssErrorModel.named("consumer")
    # The dispatch keeps the other models' random streams as they were.
    a = simulate_flight_gnss(consumer, 0.0, 60.0, lawnmower, np.random.default_rng(2))
    b = simulate_gnss(consumer, 0.0, 60.0, np.random.default_rng(2))
    np.testing.assert_array_equal(a.error_enu, b.error_enu)
    field = simulate_flight_gnss(FieldGnssModel(), 0.0, 60.0, lawnmower, np.random.default_rng(2))
    summary = field.summary()
    assert summary["mode"] == "field" and "multipath_zones" in summary
    assert "nothing in the pipeline was tuned" in FieldGnssModel().to_dict()["note"]

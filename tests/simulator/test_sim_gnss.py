"""GNSS error models: stand-alone GPS (metres, drifting, vertical 2-3x) and RTK (cm)."""

import numpy as np
import pytest

from worker.simulator.gnss import (
    GnssErrorModel,
    ImuErrorModel,
    simulate_attitude_errors,
    simulate_gnss,
)


def test_standalone_bias_is_metres_fresh_per_flight_and_worse_vertically():
    model = GnssErrorModel.named("standalone")
    rng = np.random.default_rng(0)
    biases, within = [], []
    for _ in range(300):
        tr = simulate_gnss(model, 0.0, 120.0, rng)
        biases.append(tr.error_enu.mean(axis=0))
        within.append(tr.error_enu.std(axis=0))
    b = np.array(biases)
    horiz = np.sqrt((b[:, :2] ** 2).mean())
    vert = np.sqrt((b[:, 2] ** 2).mean())
    assert 1.0 < horiz < 2.5  # "a bias of a few metres"
    assert 2.0 <= vert / horiz <= 3.0
    # Slow drift plus noise within a flight: much smaller than the bias.
    w = np.array(within).mean(axis=0)
    assert w[0] < 0.5 * horiz and w[2] < 0.5 * vert
    # Independent between flights.
    assert abs(np.corrcoef(b[:-1, 0], b[1:, 0])[0, 1]) < 0.2


def test_rtk_is_centimetres():
    tr = simulate_gnss(GnssErrorModel.named("rtk"), 0.0, 60.0, np.random.default_rng(1))
    assert np.abs(tr.error_enu[:, :2]).max() < 0.08
    assert np.abs(tr.error_enu[:, 2]).max() < 0.15


def test_none_is_exact_and_unknown_modes_fail():
    tr = simulate_gnss(GnssErrorModel.named("none"), 0.0, 10.0, np.random.default_rng(2))
    assert not tr.error_enu.any()
    with pytest.raises(ValueError, match="unknown GNSS mode"):
        GnssErrorModel.named("dgps")


def test_attitude_errors_are_imu_level():
    att = simulate_attitude_errors(ImuErrorModel(), 0.0, 60.0, np.random.default_rng(3))
    a, g = att.at(np.linspace(0, 60, 600))
    assert np.std(a[:, 1]) < 0.2 and np.std(a[:, 2]) < 0.2
    assert np.allclose(np.mean(a[:, 0]), att.yaw_bias, atol=0.1)
    assert np.std(g[:, 1]) < 0.1

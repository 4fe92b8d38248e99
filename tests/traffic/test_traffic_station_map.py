"""The map between segment-mean density and the loop stations' scale: fit, inverse, monotonicity."""

from __future__ import annotations

import numpy as np
import pytest

from corridor.traffic.macro.station_map import StationMap, fit_station_map


def test_fit_recovers_a_linear_relation_and_inverts():
    rng = np.random.default_rng(0)
    truth = rng.uniform(0.0, 60.0, 5000)
    station = 1.3 * truth + rng.normal(0.0, 4.0, truth.size)
    g = fit_station_map(truth, station)
    x = np.array([10.0, 25.0, 40.0, 55.0])
    assert np.allclose(g.to_station(x), 1.3 * x, atol=1.5)
    assert np.allclose(g.to_segment(g.to_station(x)), x, atol=1e-9)
    assert abs(g.residual_sd - 4.0) < 0.5
    assert np.all(np.diff(g.station) > 0) and np.all(np.diff(g.segment) > 0)


def test_monotone_even_when_bin_medians_dip_and_one_to_one_beyond_the_data():
    truth = np.repeat([2.5, 7.5, 12.5, 17.5], 50)
    station = np.repeat([3.0, 9.0, 8.0, 20.0], 50)  # the third bin's median dips
    g = fit_station_map(truth, station)
    assert np.all(np.diff(g.station) > 0)
    assert g.to_station(np.array([27.5]))[0] == pytest.approx(g.station[-1] + 10.0)
    assert g.to_segment(np.array([g.station[-1] + 30.0]))[0] == pytest.approx(17.5 + 30.0)
    assert g.to_segment(np.array([-5.0]))[0] == 0.0


def test_too_few_bins_is_an_error():
    with pytest.raises(ValueError, match="at least 2 density bins"):
        fit_station_map(np.full(30, 3.0), np.full(30, 4.0))


def test_load_round_trip(tmp_path):
    p = tmp_path / "m.json"
    p.write_text('{"segment": [0, 10, 40], "station": [0, 12, 55], "residual_sd": 7.5}')
    g = StationMap.load(p)
    assert g.to_station(np.array([25.0]))[0] == pytest.approx(33.5) and g.residual_sd == 7.5

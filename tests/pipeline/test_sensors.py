from __future__ import annotations

import numpy as np
import pytest

from pipeline.sensors import PRESETS, get_sensor, ouster_from_metadata


def test_sensors_hdl32e_matches_datasheet():
    s = get_sensor("hdl32e")
    assert s.n_rings == 32 and s.width == 2160
    el = np.asarray(s.elevations_deg)
    assert el[0] == pytest.approx(10.67) and el[-1] == pytest.approx(-30.67)
    assert np.diff(el) == pytest.approx(np.full(31, -1.333), abs=2e-3)


def test_sensors_presets_have_descending_elevations():
    for s in PRESETS.values():
        assert np.all(np.diff(s.elevations_deg) < 0), s.name


def test_sensors_unknown_name_raises_keyerror():
    with pytest.raises(KeyError, match="unknown sensor"):
        get_sensor("hdl99")


def test_sensors_ouster_from_metadata(real_data):
    s = ouster_from_metadata(real_data / "ouster" / "OS-1-32-G_v2.1.1_1024x10.json")
    assert s.n_rings == 32 and s.width == 1024 and s.frequency_hz == 10

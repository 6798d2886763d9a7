"""Regional channel plans, hopping, and the tag population's spreads and detuning."""

import numpy as np
import pytest

import scenes
from pipeline.acquisition import ReaderConfig, TagPopulation, draw_population, reader_response
from pipeline.acquisition.channels import REGIONS, channel_schedule, hop_sequence
from pipeline.acquisition.population import surface_materials
from pipeline.config import config_from_mapping
from pipeline.configschema import ConfigError


def test_region_profiles():
    etsi = ReaderConfig().channel_plan()
    np.testing.assert_allclose(etsi.channels_hz, [865.7e6, 866.3e6, 866.9e6, 867.5e6])
    assert etsi.dwell_s == 4.0 and etsi.region.max_eirp_dbm == 35.15
    fcc = ReaderConfig(region="FCC").channel_plan()
    assert len(fcc.channels_hz) == 50 and fcc.dwell_s == 0.4
    np.testing.assert_allclose(fcc.channels_hz[[0, -1]], [902.75e6, 927.25e6])
    np.testing.assert_allclose(np.diff(fcc.channels_hz), 0.5e6)
    none = ReaderConfig(region="none").channel_plan(866e6)
    np.testing.assert_array_equal(none.channels_hz, [866e6])
    assert not np.isfinite(none.dwell_s)
    explicit = ReaderConfig(channels_hz=(866.3e6, 867.5e6), channel_dwell_s=1.0).channel_plan()
    np.testing.assert_array_equal(explicit.channels_hz, [866.3e6, 867.5e6])


@pytest.mark.parametrize("reader, key", [
    ({"region": "JP"}, "region"),
    ({"channels_hz": [915e6]}, "channels_hz"),  # outside ETSI's 865-868 MHz
    ({"region": "FCC", "channels_hz": [866e6]}, "channels_hz"),
    ({"channel_dwell_s": 0.0}, "channel_dwell_s"),
    ({"region": "FCC", "channel_dwell_s": 1.0}, "channel_dwell_s"),  # > 0.4 s
    ({"phase_noise_rad": -0.1}, "phase_noise_rad"),
    ({"tag_sensitivity_spread_db": -1.0}, "tag_sensitivity_spread_db"),
])
def test_bad_regional_settings_are_named(reader, key):
    with pytest.raises(ConfigError, match=key):
        config_from_mapping({"reader": reader}, source="study.toml")


def test_hop_sequence_and_schedule():
    plan = ReaderConfig(region="FCC").channel_plan()
    hopped = hop_sequence(plan, np.random.default_rng(0))
    assert sorted(hopped.channels_hz) == sorted(plan.channels_hz)
    assert not np.array_equal(hopped.channels_hz, plan.channels_hz)  # pseudo-random order
    t = np.array([0.0, 0.39, 0.4, 0.81, 0.4 * 50 + 0.1])
    np.testing.assert_array_equal(channel_schedule(t, hopped), [0, 0, 1, 2, 0])


def test_population_spreads_and_detuning():
    n = 4000
    tags = scenes.TagSet([f"t{i}" for i in range(n)], np.zeros((n, 3)), np.tile([0, 1.0, 0], (n, 1)))
    mats = np.where(np.arange(n) % 4 == 0, "metal", "brick")
    pop = draw_population(tags, ReaderConfig(tag_sensitivity_spread_db=1.5, tag_modulation_spread_db=1.0,
                                             metal_detuning_loss_db=10.0, metal_tag_type="dipole"),
                          np.random.default_rng(0), mats)
    # 5 standard errors of mean and std of n normal draws
    assert abs(pop.sensitivity_offset_db.mean()) < 5 * 1.5 / np.sqrt(n)
    assert abs(pop.sensitivity_offset_db.std() - 1.5) < 5 * 1.5 / np.sqrt(2 * n)
    assert abs(pop.modulation_offset_db.std() - 1.0) < 5 / np.sqrt(2 * n)
    np.testing.assert_array_equal(pop.detuning_loss_db, np.where(mats == "metal", 10.0, 0.0))
    d = pop.to_dict()
    assert len(d["detuning_loss_db"]) == n and d["surface_material"][0] == "metal"
    nominal = draw_population(tags, ReaderConfig(tag_sensitivity_spread_db=0.0, tag_modulation_spread_db=0.0,
                                                 metal_detuning_loss_db=0.0),
                              np.random.default_rng(0), mats)
    assert not nominal.sensitivity_offset_db.any() and not nominal.detuning_loss_db.any()
    # the default: a tag on metal is an on-metal tag type, which the metal does not detune
    default = draw_population(tags, ReaderConfig(), np.random.default_rng(0), mats)
    assert ReaderConfig().metal_detuning_loss_db == 10.0 and not default.detuning_loss_db.any()
    with pytest.raises(ConfigError, match="metal_tag_type"):
        ReaderConfig(metal_tag_type="patch")


def test_tag_deviations_in_the_budget():
    # P_tag = 30 + g - 3, P_rx = 30 + 2 g - 6 - 2 * 3 (see test_reader.py), then the tag's own
    # deviations: a 4 dB detuning loss once forward and twice back, a -2 dB modulation offset.
    reader = ReaderConfig(tx_power_dbm=30.0, rssi_noise_db=0.0, rssi_resolution_db=0.0,
                          anticollision_miss_probability=0.0, polarization_loss_db=3.0)
    g = np.array([-40.0, -40.0, -40.0])
    resp = reader_response(g, reader, np.random.default_rng(0), sensitivity_offset_db=[0.0, 0.0, 2.0],
                           modulation_offset_db=[0.0, -2.0, 0.0], tag_loss_db=[0.0, 4.0, 4.0])
    np.testing.assert_allclose(resp.tag_power_dbm, [-13.0, -17.0, -17.0])
    np.testing.assert_allclose(resp.rx_power_dbm, [-62.0, -72.0, -70.0])
    # the third tag is 2 dB less sensitive: -17 dBm no longer powers it
    np.testing.assert_array_equal(resp.read, [True, True, False])


def test_surface_materials_of_tags():
    sc = scenes.corridor(length_m=6.0, width_m=2.4, height_m=2.5,
                         tags=[{"id": "wall", "position_m": (2.0, 2.4, 1.0)}], name="mat_test")
    # a scene's tags sit on surfaces; a tag set may also hold one in mid-air
    tags = scenes.TagSet(["wall", "air"], [sc.tags.positions_m[0], [2.0, 1.2, 1.0]],
                         [sc.tags.normals[0], [0.0, 1.0, 0.0]])
    mats = surface_materials(sc, tags)
    assert mats[1] == "" and mats[0] in sc.materials
    assert isinstance(draw_population(tags, ReaderConfig(), np.random.default_rng(0), mats),
                      TagPopulation)


def test_regions_table_is_consistent():
    for name, prof in REGIONS.items():
        if prof.band_hz is not None:
            lo, hi = prof.band_hz
            assert all(lo <= c <= hi for c in prof.channels_hz), name


def test_reported_channels_fill_within_half_a_dwell_by_hand():
    from pipeline.acquisition.channels import channel_plan, reported_channels

    plan = channel_plan("ETSI", channel_dwell_s=4.0)
    chans = np.asarray(plan.channels_hz)
    t = np.arange(12) * 0.5  # slots every 0.5 s, antenna 0
    cycle, antenna = np.arange(12), np.zeros(12, int)
    # reads in slot 2 (t 1.0 s) on channel 1, and in slot 10 (t 5.0 s) on channel 3 (+300 Hz
    # of the reader's rounding: still that channel)
    reported = {(2, 0): float(chans[1]), (10, 0): float(chans[3]) + 300.0}
    index, freq, counts = reported_channels(t, cycle, antenna, plan, reported)
    # half the dwell (2 s): slots 0-6 (t <= 3.0 s, nearest slot 2) take channel 1; slots
    # 7-11 (t >= 3.5 s, nearest slot 10, within 2 s from 3.0 s on) take channel 3
    assert index.tolist() == [1] * 7 + [3] * 5
    assert freq[10] == chans[3]
    assert counts == {"n_slots": 12, "reported": 2, "filled_within_dwell": 10, "hop_sequence": 0}
    # a slot farther than half a dwell from every report keeps the hop sequence (-1)
    index, freq, counts = reported_channels(np.r_[t, 20.0], np.r_[cycle, 12], np.r_[antenna, 0],
                                            plan, reported)
    assert index[-1] == -1 and np.isnan(freq[-1]) and counts["hop_sequence"] == 1
    # nothing reported: every slot keeps its hop
    index, _, counts = reported_channels(t, cycle, antenna, plan, {})
    assert (index == -1).all() and counts["reported"] == 0

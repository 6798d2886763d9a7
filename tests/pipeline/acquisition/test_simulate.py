"""simulate_reads on a small real scene with real (low-ray-count) Sionna traces."""

import numpy as np
import pytest

import scenes
from pipeline.acquisition import (
    PoseTrack,
    ReaderConfig,
    ReadLog,
    read_attempts,
    simulate_reads,
    ssm_samples,
    tdm_samples,
)
from pipeline.robot.kinematics import Robot, antenna_poses
from propagation import TraceOptions, antenna_frame_angles
from propagation.constants import SPEED_OF_LIGHT

# Low ray count and depth: these tests check bookkeeping, not path convergence.
TRACE = TraceOptions(method="direct", max_depth=2, samples_per_src=2000)
# 8 dBm conducted: free-space maximum range with both maximum pattern gains and the
# 6 dB margin is lambda / (4 pi) * 10^((8 + 8 + 2.15 - 3 + 18 + 6) / 20) = 2.5 m.
# 5 dBm: a 2.5 m range at a 6 dB margin (the polarisation mismatch is in the traced gain)
SHORT_BUDGET = {"tx_power_dbm": 5.0}


@pytest.fixture(scope="module")
def scene():
    return scenes.corridor(
        length_m=6.0,
        width_m=2.4,
        height_m=2.5,
        tags=[
            {"id": "near_left", "position_m": (2.2, 2.4, 1.0)},
            {"id": "near_right", "position_m": (2.0, 0.0, 0.7)},
            {"id": "far", "position_m": (5.5, 2.4, 1.0)},
        ],
        name="acq_test",
    )


@pytest.fixture(scope="module")
def track():
    t = np.linspace(0.0, 2.0, 21)
    true = np.column_stack([np.linspace(0.8, 1.6, 21), np.full(21, 1.2), np.zeros(21)])
    est = true + np.array([0.05, -0.03, 0.02])  # a localisation error
    return PoseTrack(t, true, est, np.full_like(true, np.nan))


def _reader(**kw):
    # 10 read cycles/s: one per pose of the 21-pose, 2 s track
    base = dict(read_rate_hz=10.0, rssi_noise_db=1.0, rssi_resolution_db=0.5,
                anticollision_miss_probability=0.05)
    return ReaderConfig(**{**base, **kw.pop("budget", {}), **kw})


def test_out_of_range_tags_are_not_traced(scene, track, tmp_path):
    # the carrier only and nominal tags: the range is the budget's at 865 MHz
    reader = _reader(budget=SHORT_BUDGET, range_margin_db=6.0, region="none",
                     tag_sensitivity_spread_db=0.0)
    assert reader.link_budget().max_range_m(margin_db=6.0) == pytest.approx(2.5, rel=0.01)
    log = simulate_reads(scene, Robot(), track, reader, np.random.default_rng(0), trace=TRACE)
    r = log.reads
    far = r["tag_id"] == "far"
    # The far tag is >= 3.4 m from every antenna pose: no pair of it is traced.
    assert r.loc[far, "d_true_m"].min() > 3.4
    assert not r.loc[far, "in_range"].any() and not r.loc[far, "read"].any()
    assert np.all(np.isneginf(r.loc[far, "gain_db"]))
    # Traced pairs are exactly those within the maximum range (all 21 poses distinct).
    within = r["d_true_m"] <= reader.link_budget().max_range_m(margin_db=6.0)
    np.testing.assert_array_equal(r["in_range"], within)
    assert log.metadata["n_pairs_traced"] == int(within.sum())
    assert log.metadata["n_pairs_traced"] < log.metadata["n_pairs"]


def test_reads_consistent_and_geometry(scene, track):
    reader = _reader()
    log = simulate_reads(scene, Robot(), track, reader, np.random.default_rng(1), trace=TRACE)
    r = log.reads
    assert len(r) == 21 * 3  # round robin: one antenna per cycle, every tag
    np.testing.assert_array_equal(r["antenna"].to_numpy()[::3], np.arange(21) % 2)
    assert not (r["read"] & ~(r["powered"] & r["in_range"])).any()
    np.testing.assert_array_equal(r["rssi_dbm"].isna(), ~r["read"])
    assert r["read"].sum() > 0  # near tags at 1-2 m are read by a 27 dBm reader
    # Every read satisfies both thresholds of the budget (before RSSI noise), the tag's
    # own sensitivity (drawn per tag, recorded in the metadata); float32 storage.
    rd = r[r["read"]]
    pop = log.metadata["tag_population"]
    offset = dict(zip(pop["tag_ids"], pop["sensitivity_offset_db"], strict=True))
    threshold = reader.tag_sensitivity_dbm + rd["tag_id"].astype(str).map(offset).astype(float)
    assert (rd["tag_power_dbm"] >= threshold - 1e-4).all()
    assert (rd["rx_power_dbm"] >= reader.reader_sensitivity_dbm).all()
    # Geometry columns equal the antenna-frame geometry of the composed antenna poses.
    ant = antenna_poses(track.true_poses, Robot().antennas)[np.arange(21), np.arange(21) % 2]
    g = antenna_frame_angles(ant, scene.tags.positions_m)
    # float32 storage: 1e-5 relative.
    np.testing.assert_allclose(r["d_true_m"], g.d_m.reshape(-1), rtol=1e-5)
    np.testing.assert_allclose(r["alpha_true_rad"], g.alpha_rad.reshape(-1), atol=1e-5)
    # The localisation error moves the estimated geometry.
    assert np.abs(r["d_est_m"] - r["d_true_m"]).max() > 0.01
    # Training sets come out of the log.
    ss = ssm_samples(r, d_max_m=3.0, pose="est")
    assert len(ss) == int((r["read"] & (r["d_est_m"] < 3.0)).sum())
    td = tdm_samples(r, d_max_m=3.0, pose="true")
    assert td.n_pos.sum() == int((r["read"] & (r["d_true_m"] < 3.0)).sum())


def test_same_seed_identical_files_and_cache(scene, track, tmp_path):
    import propagation
    from propagation.backend import CUDA_VARIANT, ensure_variant

    if ensure_variant() == CUDA_VARIANT:
        pytest.skip("bit-reproducible traces need the CPU variant: set_deterministic refuses CUDA")
    reader = _reader()
    # run0 and run1 trace from scratch (separate caches); run2 reuses run0's cache.
    # Fresh traces are bit-identical only on one Dr.Jit thread (propagation.set_deterministic).
    propagation.set_deterministic(True)
    try:
        for k, cache in enumerate(("cache0", "cache1", "cache0")):
            log = simulate_reads(
                scene,
                Robot(),
                track,
                reader,
                np.random.default_rng(7),
                trace=TRACE,
                cache_dir=tmp_path / cache,
            )
            log.write(tmp_path / f"run{k}")
    finally:
        propagation.set_deterministic(False)
    for name in ("reads.parquet", "poses.parquet"):
        a = (tmp_path / "run0" / name).read_bytes()
        for k in (1, 2):
            assert a == (tmp_path / f"run{k}" / name).read_bytes(), (name, k)
    back = ReadLog.read(tmp_path / "run0")
    np.testing.assert_array_equal(back.reads["read"], log.reads["read"])
    other = simulate_reads(
        scene,
        Robot(),
        track,
        reader,
        np.random.default_rng(8),
        trace=TRACE,
        cache_dir=tmp_path / "cache0",
    )
    # A different seed changes the RSSI noise of at least one read.
    assert not np.array_equal(
        other.reads["rssi_dbm"].fillna(0).to_numpy(), log.reads["rssi_dbm"].fillna(0).to_numpy()
    )


def test_all_antennas_mode_schedule(track):
    reader = _reader(antenna_mode="all", read_rate_hz=5.0)
    att = read_attempts(track, Robot().antennas, reader)
    # 2 s at 5 Hz: cycles at 0, 0.2, ..., 2.0 s; the second antenna's slot at +0.1 s
    # falls after the track's end for the last cycle.
    assert att.cycle.max() == 10
    np.testing.assert_array_equal(att.antenna[:4], [0, 1, 0, 1])
    np.testing.assert_allclose(att.time_s[:4], [0.0, 0.1, 0.2, 0.3], atol=1e-12)
    assert len(att.time_s) == 21


def test_trace_is_trace_options_not_keywords(scene, track):
    # the links, frequency and channels are the reader's; the tracer's options come whole
    with pytest.raises(TypeError, match="TraceOptions"):
        simulate_reads(
            scene, Robot(), track, _reader(), np.random.default_rng(0), trace={"frequency_hz": 1e9}
        )


def test_channels_phase_and_doppler_columns(scene, track, tmp_path):
    # ETSI: 4 channels, a hop every 0.5 s of the 2 s track; the fixed inventory (0/1 counts)
    reader = _reader(channel_dwell_s=0.5, inventory="fixed")
    log = simulate_reads(scene, Robot(), track, reader, np.random.default_rng(2), trace=TRACE,
                         cache_dir=tmp_path / "cache")
    r = log.reads
    hops = log.metadata["channels"]["hop_sequence_hz"]
    assert sorted(hops) == [865.7e6, 866.3e6, 866.9e6, 867.5e6]
    # attempt at t uses hop floor(t / 0.5) of the sequence
    k = np.floor(r["time_s"].to_numpy() / 0.5 + 1e-9).astype(int) % 4
    np.testing.assert_array_equal(r["frequency_hz"].to_numpy(), np.asarray(hops)[k])
    rd = r["read"].to_numpy()
    ph = r["phase_rad"].to_numpy()
    assert rd.sum() > 0
    assert np.all((ph[rd] >= 0) & (ph[rd] < 2 * np.pi)) and np.isnan(ph[~rd]).all()
    dop = r["doppler_hz"].to_numpy()
    # 0.4 m/s antenna: |f_D| <= 2 v / lambda = 2.3 Hz for every path (the direction
    # derivative of each path's phase is bounded by the wavenumber)
    assert np.isfinite(dop[rd]).all() and np.isnan(dop[~rd]).all()
    assert np.abs(dop[rd]).max() <= 2 * 0.4 * 867.5e6 / SPEED_OF_LIGHT * 1.001
    np.testing.assert_array_equal(r["seen_count"].to_numpy(), rd.astype(int))  # fixed inventory
    assert len(log.metadata["phase_offsets_rad"]) == 2 and len(log.metadata["phase_offsets_rad"][0]) == 4
    assert len(log.metadata["tag_population"]["sensitivity_offset_db"]) == 3
    # one trace per antenna position: another region on the same cache traces nothing new
    packs = {p: p.stat().st_mtime_ns for p in (tmp_path / "cache").rglob("*") if p.is_file()}
    assert packs
    fcc = simulate_reads(scene, Robot(), track, _reader(region="FCC", tx_power_dbm=28.0),
                         np.random.default_rng(2), trace=TRACE, cache_dir=tmp_path / "cache")
    assert {p: p.stat().st_mtime_ns for p in (tmp_path / "cache").rglob("*") if p.is_file()} == packs
    assert fcc.reads["frequency_hz"].between(902e6, 928e6).all()
    log.write(tmp_path / "run")
    back = ReadLog.read(tmp_path / "run")
    np.testing.assert_array_equal(back.reads["phase_rad"].isna(), ~rd)


def test_gen2_inventory_along_a_track(scene, track):
    reader = _reader(inventory="gen2")
    log = simulate_reads(scene, Robot(), track, reader, np.random.default_rng(3), trace=TRACE)
    r = log.reads
    g2 = log.metadata["gen2"]
    assert g2["dwell_s"] == pytest.approx(0.1 - 0.005)  # 10 Hz slots less the switching time
    assert g2["n_single"] == int(r["seen_count"].sum()) > 0
    # a powered, heard tag in a 95 ms dwell with at most two others is read many times
    assert r.loc[r["read"], "seen_count"].min() >= 1 and r["seen_count"].max() > 5
    assert not (r["read"] & ~r["powered"]).any()

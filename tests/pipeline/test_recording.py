"""Recordings: a study exported in sllurp's CSV layout reads back to the same reads and
poses; bad files stop with file:line and the column; the time alignment by hand."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from pipeline.apps.cli import app
from pipeline.apps.export.csv_export import EPOCH_S, epc_of, tag_id_of
from pipeline.recording import (
    RecordingError,
    align_reads,
    read_poses_csv,
    read_sllurp_csv,
    read_tags_csv,
)

HEADER = "timestamp,reader,antenna,rssi,epc\r\n"


def test_export_then_import_gives_the_same_reads_and_poses(tiny_study, tmp_path):
    out = tmp_path / "rec"
    res = CliRunner().invoke(app, ["export", str(tiny_study.run), "--out", str(out)])
    assert res.exit_code == 0, res.output
    # sllurp's own layout: excel dialect (CRLF), its header, whole-dBm RSSI
    raw = (out / "reads.csv").read_bytes()
    assert raw.startswith(HEADER.encode()) and b"\r\n" in raw
    got = read_sllurp_csv(out / "reads.csv")
    want = pd.read_parquet(tiny_study.run / "reads.parquet")
    want = want[want["read"]]
    assert len(got) == len(want) > 0
    np.testing.assert_allclose(got["t_s"] - EPOCH_S, want["time_s"], atol=1e-6)
    assert (got["antenna_port"].to_numpy() == want["antenna"].to_numpy() + 1).all()
    np.testing.assert_array_equal(got["rssi_dbm"], np.round(want["rssi_dbm"].to_numpy(float)))
    assert [tag_id_of(e) for e in got["epc"]] == want["tag_id"].astype(str).tolist()
    # the poses at the reads' times: the estimated track, interpolated
    poses = read_poses_csv(out / "poses.csv")
    aligned, dropped = align_reads(got, poses)
    assert dropped == 0
    with np.load(tiny_study.run / "tour" / "train_track.npz") as z:
        x = np.interp(got["t_s"] - EPOCH_S, z["t_s"], z["est"][:, 0])
    np.testing.assert_allclose(aligned["x_m"], x, atol=2e-6)  # the CSV's micrometres
    tags = read_tags_csv(out / "tags.csv")
    assert set(got["epc"]) <= set(tags["epc"])
    assert "left" in (out / "mounts.toml").read_text()
    # a second export into the same folder is allowed (its own files), a user's file is not
    assert CliRunner().invoke(app, ["export", str(tiny_study.run), "--out", str(out)]).exit_code == 0
    user = tmp_path / "mine"
    user.mkdir()
    (user / "reads.csv").write_text("my reads")
    bad = CliRunner().invoke(app, ["export", str(tiny_study.run), "--out", str(user)])
    assert bad.exit_code == 2 and (user / "reads.csv").read_text() == "my reads"


@pytest.mark.parametrize("body, words", [
    ("", "empty file"),
    ("timestamp,reader,antenna,epc\r\n1.0,r:1,1,AB\r\n", "missing column 'rssi'"),
    (HEADER + "1.0,r:1,1,-50,ABCD\r\n2.0,r:1,one,-50,ABCD\r\n", ":3: column 'antenna'"),
    (HEADER + "1.0,r:1,1,-50,XYZ!\r\n", ":2: column 'epc'"),
    (HEADER + "1.0,r:1,0,-50,ABCD\r\n", "port 0"),
    (HEADER + "1.0,r:1,1,nan,ABCD\r\n", "column 'rssi'.*not finite"),
    (HEADER, "no reads"),
])
def test_bad_reads_files_name_file_line_and_column(tmp_path, body, words):
    p = tmp_path / "reads.csv"
    p.write_text(body, newline="")
    with pytest.raises(RecordingError, match=words) as exc:
        read_sllurp_csv(p)
    assert str(p) in str(exc.value) and "\n" not in str(exc.value)


def test_poses_and_tags_files_are_checked(tmp_path):
    p = tmp_path / "poses.csv"
    p.write_text("t_s,x_m,y_m,yaw_rad\n0,0,0,0\n0,1,0,0\n")
    with pytest.raises(RecordingError, match=r":3: column 't_s'.*must increase"):
        read_poses_csv(p)
    t = tmp_path / "tags.csv"
    t.write_text("epc,x_m,y_m,z_m\nAB,0,0,1\nab,1,0,1\n")
    with pytest.raises(RecordingError, match=r":3: .*listed twice \(line 2"):
        read_tags_csv(t)


def test_alignment_by_hand():
    """Reads between poses get the linear interpolation; the yaw the short way through
    +-pi; a read outside the poses' span is dropped and counted, not extrapolated."""
    poses = pd.DataFrame({"t_s": [0.0, 2.0], "x_m": [0.0, 2.0], "y_m": [1.0, 1.0],
                          "yaw_rad": [3.0, -3.0]})  # 3 rad to -3 rad: 0.283 rad the short way
    reads = pd.DataFrame({"t_s": [1.0, 2.5], "epc": ["AB", "AB"]})
    a, dropped = align_reads(reads, poses)
    assert dropped == 1 and len(a) == 1
    assert a["x_m"].iloc[0] == pytest.approx(1.0)
    assert abs(a["yaw_rad"].iloc[0]) == pytest.approx(np.pi, abs=1e-9)  # halfway across pi


def test_epcs_carry_the_tag_ids():
    assert epc_of("T01") == "000000000000000000543031" and tag_id_of(epc_of("T01")) == "T01"
    with pytest.raises(ValueError, match="96-bit"):
        epc_of("a-very-long-tag-id")


def test_a_real_sllurp_log_reads(tmp_path):
    """As an Impinj R420 logged by sllurp on Python 3 writes it (a public project's log,
    crozenboom/RFID-Locate-main Testing/Test8, rows reproduced in shape): the EPC as the
    bytes' repr, report batches of several ports out of time order, --impinj-reports
    columns after sllurp's five."""
    p = tmp_path / "reads.csv"
    p.write_text("timestamp,reader,antenna,rssi,epc,phase_angle,channel_index,doppler_frequency\n"
                 "1746738549.279919,192.168.0.219:5084,1,-52,b'303435fc8803d056d15b963f',3292,2,39\n"
                 "1746738549.188597,192.168.0.219:5084,2,-63,b'303435fc8803d056d15b963f',3932,2,2367\n"
                 "1746738549.251187,192.168.0.219:5084,4,-62,b'303435fc8803d056d15b963f',4064,3,839\n")
    r = read_sllurp_csv(p, region="FCC")  # its channel indices run to 50: the FCC table
    assert r["epc"].tolist() == ["303435FC8803D056D15B963F"] * 3
    assert r["antenna_port"].tolist() == [2, 4, 1] and r["t_s"].is_monotonic_increasing
    assert r.attrs["n_reordered"] == 2
    p.write_text("timestamp,reader,antenna,rssi,epc\n1.0,r:1,1,-50,b'XYZ'\n")
    with pytest.raises(RecordingError, match=":2: column 'epc'"):
        read_sllurp_csv(p)


def test_sllurp_impinj_columns_in_si_by_hand(tmp_path):
    """The Impinj fields users add to sllurp's logger (a public R420 project's layout), in
    the reader's raw units: phase 3468/4096 of a turn, channel 7 of the FCC table (902.75
    MHz + 6 x 0.5 MHz), Doppler -127/16 Hz; an empty field is NaN."""
    p = tmp_path / "reads.csv"
    head = "timestamp,reader,antenna,rssi,epc,phase_angle,channel_index,doppler_frequency\n"
    p.write_text(head + "1747166391.767558,192.168.0.219:5084,1,-67,b'303435fc8803d056d15b963f',3468,7,-127\n"
                 "1747166391.80,192.168.0.219:5084,2,-36,b'303435fc8803d056d15b963f',,,\n")
    r = read_sllurp_csv(p, region="FCC")
    assert r["phase_rad"].iloc[0] == pytest.approx(3468 * 2 * np.pi / 4096)  # 5.3198 rad
    assert r["frequency_hz"].iloc[0] == pytest.approx(905.75e6)
    assert r["doppler_hz"].iloc[0] == pytest.approx(-7.9375)
    assert r[["phase_rad", "frequency_hz", "doppler_hz"]].iloc[1].isna().all()
    with pytest.raises(RecordingError, match=r":2: column 'channel_index': .*recording.region"):
        read_sllurp_csv(p)  # a channel index needs the region's table
    p.write_text(head + "1.0,r:1,1,-50,3034,4096,7,0\n")
    with pytest.raises(RecordingError, match=r":2: column 'phase_angle': 4096 is outside 0-4095"):
        read_sllurp_csv(p, region="FCC")
    p.write_text(head + "1.0,r:1,1,-50,3034,1,51,0\n")
    with pytest.raises(RecordingError, match=r":2: column 'channel_index': channel index 51 is outside FCC"):
        read_sllurp_csv(p, region="FCC")

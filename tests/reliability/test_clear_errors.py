"""The unclear errors of issue 33's battery, each now one line naming the file, key or value.

Reader and tracing values are refused when the config is read (exit 2, no run directory);
the propagation cache, the memory budget against the machine, a mesh path and the files
of a run directory are named where they are met; a write into a full disk says so and
names the file (a real ENOSPC from /dev/full, which every write to fails with it).
"""

from __future__ import annotations

import errno
import os
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from typer.testing import CliRunner

from pipeline.apps.cli import app
from pipeline.config import ConfigError, StudyConfig, replace_path

ROOT = Path(__file__).resolve().parents[2]
TINY = str(ROOT / "configs" / "tiny.toml")


def _run(tmp_path, *sets, target=TINY, env=None):
    out = tmp_path / "run"
    args = ["run", target, "--no-progress", "--out", str(out)]
    for s in sets:
        args += ["--set", s]
    return CliRunner().invoke(app, args, env=env), out


@pytest.mark.parametrize("setting, words", [
    # read_rate_hz = 1e300 used to blame reader.gen2.antenna_switch_s
    ("reader.read_rate_hz=1e300", "read_rate_hz = 1e+300: more than its upper bound 1,000"),
    ("reader.read_rate_hz=300", "reader.read_rate_hz = 300.0 gives antenna slots of 0.003333 s"),
    # tx_power_dbm = 1000 used to fail at the models stage
    ("reader.tx_power_dbm=1000", "reader.tx_power_dbm = 1000.0 dBm: outside [0, 36] dBm"),
    ("reader.tx_power_dbm=-40", "reader.tx_power_dbm = -40.0 dBm: outside [0, 36] dBm"),
    # an unknown pattern used to fail at the reads stage
    ('tracing.reader_pattern="nope"', "tracing.reader_pattern = 'nope': unknown antenna pattern"),
    ('tracing.tag_pattern="nope"', "tracing.tag_pattern = 'nope': unknown antenna pattern"),
    ('tracing.reader_polarization="X"', "tracing.reader_polarization = 'X': unknown"),
])
def test_reader_and_tracing_values_are_refused_when_the_config_is_read(tmp_path, setting, words):
    res, out = _run(tmp_path, setting)
    assert res.exit_code == 2, res.output
    assert words in res.output and "tiny.toml" in res.output
    assert len(res.output.strip().splitlines()) == 1 and not out.exists()


def test_the_transmit_power_bounds_are_the_regulations_not_the_default():
    assert replace_path(StudyConfig(), "reader.tx_power_dbm", 36.0).reader.tx_power_dbm == 36.0
    assert StudyConfig().reader.tx_power_dbm == pytest.approx(35.15 - 8.0)  # ETSI 2 W ERP
    with pytest.raises(ConfigError, match="outside"):
        replace_path(StudyConfig(), "reader.tx_power_dbm", 36.01)


def _ctx(cache_dir=""):
    return SimpleNamespace(config=replace_path(StudyConfig(), "tracing.cache_dir", cache_dir))


def test_a_cache_dir_that_cannot_be_a_directory_is_named(tmp_path, monkeypatch):
    from pipeline.stages.checks import check_cache_dir

    afile = tmp_path / "afile"
    afile.write_text("mine")
    with pytest.raises(ConfigError, match=rf"tracing.cache_dir = '{afile}': {afile} is a file, "
                                          "not a directory"):
        check_cache_dir(_ctx(str(afile)))
    assert afile.read_text() == "mine"
    with pytest.raises(ConfigError, match=r"tracing.cache_dir = '/proc/rfidstudy-x': cannot make "
                                          "the propagation cache directory"):
        check_cache_dir(_ctx("/proc/rfidstudy-x"))
    monkeypatch.setenv("RFIDSTUDY_CACHE", str(afile / "sub"))
    with pytest.raises(ConfigError, match=r"\$RFIDSTUDY_CACHE = .*afile/sub'"):
        check_cache_dir(_ctx(""))
    monkeypatch.setenv("RFIDSTUDY_CACHE", str(tmp_path / "new" / "cache"))
    check_cache_dir(_ctx(""))  # a missing one is made
    assert (tmp_path / "new" / "cache").is_dir()


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into a read-only folder")
def test_a_read_only_cache_dir_is_named(tmp_path):
    from pipeline.stages.checks import check_cache_dir

    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        with pytest.raises(ConfigError, match="is not writable"):
            check_cache_dir(_ctx(str(ro)))
    finally:
        ro.chmod(0o700)


def test_a_cache_dir_that_is_a_file_stops_the_run_before_the_tour(tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("mine")
    res, out = _run(tmp_path, f'tracing.cache_dir="{afile}"')
    assert res.exit_code == 2 and "Traceback" not in res.output, res.output
    assert f"{afile} is a file, not a directory" in res.output and "File exists" not in res.output
    assert afile.read_text() == "mine" and not (out / "stages" / "tour.json").exists()


def test_a_memory_budget_above_the_machine_is_refused():
    from pipeline.stages.checks import check_memory_budget

    total_mib = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**20
    check_memory_budget(_ctx())  # the default 2 GiB fits
    over = replace_path(StudyConfig(), "tracing.memory_budget_mb", float(int(total_mib) + 1024))
    with pytest.raises(ConfigError, match=r"tracing.memory_budget_mb = \d+: more than this "
                                          r"machine's memory \([\d,]+ MiB\)"):
        check_memory_budget(SimpleNamespace(config=over))


def _pdf_into_dev_full(fig):
    # a small buffer makes the write fail inside the PDF's zlib stream: Matplotlib then
    # raises zlib's "inconsistent stream state", hiding the OSError (the battery's
    # "Stream object has no attribute pos" is the same mask at another moment)
    fh = open("/dev/full", "wb", buffering=1024)  # noqa: SIM115 - closed below, quietly
    try:
        fig.savefig(fh, format="pdf")
    finally:
        try:
            fh.close()
        except OSError:  # the flush of the rest: the disk is still full
            pass


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_a_full_disk_is_named_with_the_file_even_when_the_writer_hides_it(tmp_path):
    import zlib

    from pipeline.figures.common import new_figure
    from scenes.fileio import atomic_output

    fig = new_figure()
    fig.add_subplot().imshow(np.random.default_rng(0).random((200, 200)))
    with pytest.raises(zlib.error):  # the mask, without the translation
        _pdf_into_dev_full(fig)
    target = tmp_path / "figures" / "x.pdf"
    target.parent.mkdir()
    target.write_bytes(b"the previous figure")
    with pytest.raises(OSError) as err:
        with atomic_output(target):
            _pdf_into_dev_full(fig)
    assert err.value.errno == errno.ENOSPC and err.value.filename == str(target)
    assert "the disk holding it is full" in str(err.value)
    assert target.read_bytes() == b"the previous figure"
    assert sorted(p.name for p in target.parent.iterdir()) == ["x.pdf"]  # no temporary left


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_figures_says_the_disk_is_full_in_one_line(tmp_path, capsys):
    import typer

    from pipeline.apps.cli import _output_errors
    from pipeline.figures.common import new_figure
    from scenes.fileio import atomic_output

    fig = new_figure()
    fig.add_subplot().plot([0, 1])
    target = tmp_path / "figures" / "x.pdf"
    with pytest.raises(typer.Exit) as ex:
        with _output_errors(str(target.parent)), atomic_output(target):
            _pdf_into_dev_full(fig)
    assert ex.value.exit_code == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"error: cannot write {target}: No space left on device (the disk holding "
                   "it is full)")


def test_a_mesh_path_that_is_a_directory_says_so(tmp_path):
    (tmp_path / "meshdir").mkdir()
    spec = tmp_path / "scene.toml"
    spec.write_text('[mesh]\npath = "meshdir"\nmaterial = "concrete"\n')
    res, _ = _run(tmp_path, target=str(spec))
    assert res.exit_code in (1, 2) and "Traceback" not in res.output
    assert f"mesh file '{tmp_path / 'meshdir'}' is a directory, not a file" in res.output
    assert "does not exist" not in res.output


def test_an_npz_holding_a_pickle_or_junk_is_named_and_never_unpickled(tmp_path):
    from scenes.fileio import read_npz

    evil = tmp_path / "field_00.npz"
    np.savez(evil, plane_gain=np.array([{"runs": "code"}], dtype=object), ok=np.zeros(2))
    with read_npz(evil) as z:
        assert z["ok"].tolist() == [0.0, 0.0]
        with pytest.raises(ValueError, match=rf"{evil}: array 'plane_gain' cannot be read: Object "
                                             "arrays cannot be loaded"):
            z["plane_gain"]
        with pytest.raises(KeyError, match="no array 'gain'"):
            z["gain"]
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(ValueError, match=rf"{junk}: not a readable NPZ file"):
        with read_npz(junk):
            pass
    single = tmp_path / "one.npz"
    with open(single, "wb") as fh:
        np.save(fh, np.zeros(3))
    with pytest.raises(ValueError, match="not an NPZ file"):
        with read_npz(single):
            pass


def test_bad_files_in_a_run_directory_are_named_by_report_and_figures(tmp_path):
    from pipeline.engine.study import Stage, run_study

    def _a(ctx):
        ctx.out("a/value.json").write_text("{}")

    run = tmp_path / "run"
    run_study(StudyConfig(), run, stages=(Stage("a", _a, ("seed",)),), manifest_extra=None,
              command_line=["test"])
    (run / "config.toml").write_text("this is [ not toml")
    for command in ("report", "figures"):
        res = CliRunner().invoke(app, [command, str(run)])
        assert res.exit_code in (1, 2) and "Traceback" not in res.output, res.output
        assert f"{run / 'config.toml'}: not a valid TOML file" in res.output
    # a pickled array where a figure reads a field: named, not unpickled
    (run / "config.toml").unlink()
    (run / "fields").mkdir()
    np.savez(run / "fields" / "field_00.npz", plane_gain=np.array([{"x": 1}], dtype=object),
             plane_centers_m=np.zeros((1, 1, 3)), antenna_pose=np.zeros(6))
    from pipeline.figures.scene import _field_arrays

    with pytest.raises(ValueError, match=r"field_00.npz: array 'plane_gain' cannot be read"):
        _field_arrays(run / "fields" / "field_00.npz")

"""report.html: built from a run directory's files alone."""

import json

from pipeline.report.html import write_report


def _run_dir(tmp_path, failure=None):
    (tmp_path / "config.toml").write_text('scene = "corridor_lab"\nseed = 1\n')
    manifest = {"seed": 1, "status": "running", "failure": failure, "stages": {}}
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    metrics = {
        "models": {"anfis": {"rssi_dbm": {"mae": 4.5, "rmse": 5.6, "bias": 0.1}}},
        "localisation_split": {"difference": {"rssi_dbm.mae": 0.142, "detection.mae": -0.017}},
    }
    (tmp_path / "metrics.json").write_text(json.dumps(metrics))
    return tmp_path


def test_localisation_split_rows_are_rendered(tmp_path):
    html = write_report(_run_dir(tmp_path)).read_text()
    # evaluate_all writes the split flat ("group.metric": value); each becomes a row
    assert "<td>rssi_dbm.mae</td><td>0.142</td>" in html
    assert "<td>detection.mae</td><td>-0.017</td>" in html


def test_status_reflects_failure_not_the_running_manifest(tmp_path):
    html = write_report(_run_dir(tmp_path)).read_text()
    assert "<td>status</td><td>complete</td>" in html
    html = write_report(_run_dir(tmp_path, failure={"stage": "models"})).read_text()
    assert "<td>status</td><td>failed</td>" in html


def test_a_strangers_malformed_intervals_give_a_report_not_a_traceback(tmp_path):
    run = _run_dir(tmp_path)
    metrics = {"heldout": {"models": {}}, "intervals": {"a": [1, 2], "b": {"models": {
        "anfis": {"estimate": "5.5"}, "x": {"estimate": 1.0, "low": None, "high": 2.0}}}},
        "comparisons": {"reference": ["not", "a", "name"], "metrics": {"b": [1]}}}
    (run / "metrics.json").write_text(json.dumps(metrics))
    html = write_report(run).read_text()
    assert "<td>x</td>" in html and "no interval" in html
    assert "Traceback" not in html

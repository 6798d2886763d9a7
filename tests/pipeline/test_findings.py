"""Findings are read from the numbers: verdicts decide every comparative word."""

from __future__ import annotations

from pipeline.report.findings import findings


def _iv(est, lo, hi, unit="tag", n=16):
    return {"estimate": est, "low": lo, "high": hi, "unit": unit, "n_units": n}


def _metrics(truepose_diff, verdict):
    return {
        "intervals": {"heldout.rssi_mae_db": {
            "unit": "tag", "n_units": 16,
            "models": {"anfis": _iv(5.5, 4.6, 6.7), "joho2009": _iv(5.7, 4.8, 7.2),
                       "log_distance": _iv(6.4, 5.4, 7.5), "anfis_truepose": _iv(5.5, 4.6, 6.7)}}},
        "comparisons": {"metrics": {"heldout.rssi_mae_db": {
            "joho2009": {**_iv(0.2, -0.1, 0.5), "verdict": "not distinguishable at 95 %"},
            "log_distance": {**_iv(0.9, 0.5, 1.3), "verdict": "worse"},
            "anfis_truepose": {**_iv(*truepose_diff), "verdict": verdict}}}},
    }


def test_verdicts_decide_the_words():
    found, caveats = findings(_metrics((-0.01, -0.08, 0.07), "not distinguishable at 95 %"))
    rssi = found[0]
    assert "5.50 dB [4.60, 6.70] over 16 tags" in rssi
    assert "log-distance + pattern does worse" in rssi
    assert "Joho et al. 2009" in rssi.split("does worse")[1]  # named as not distinguishable
    assert "better" not in rssi
    assert "costs nothing measurable" in found[-1] and "+0.01 dB [-0.07, +0.08]" in found[-1]
    assert any("One study" in c for c in caveats)


def test_the_mcl_cost_sentence_follows_the_sign_of_the_comparison():
    # true-pose model better than the MCL-pose one (difference < 0): MCL poses cost
    found, _ = findings(_metrics((-0.5, -0.8, -0.2), "better"))
    assert "costs a measurable amount" in found[-1] and "+0.50 dB [+0.20, +0.80]" in found[-1]
    # true-pose model worse: MCL poses help, never "costs"
    found, _ = findings(_metrics((0.5, 0.2, 0.8), "worse"))
    assert "measurably helps" in found[-1] and "-0.50 dB [-0.80, -0.20]" in found[-1]


def test_missing_or_malformed_numbers_never_raise():
    m = _metrics((-0.5, None, None), "better")
    m["intervals"]["heldout.rssi_mae_db"]["models"]["anfis"] = _iv("5.5", None, None)
    m["intervals"]["x"] = ["not", "a", "dict"]
    m["comparisons"]["metrics"]["heldout.rssi_mae_db"]["joho2009"] = [1]
    found, caveats = findings(m)
    assert all("MCL poses" not in f for f in found)  # no interval: no claim
    assert findings({})[0] == []

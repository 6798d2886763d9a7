"""A run's findings in a few sentences, generated from its numbers, with their caveats.

Every sentence is read from ``metrics.json`` (sections ``intervals`` and ``comparisons``,
:mod:`pipeline.evaluation.headline`): an estimate is quoted with its 95 % interval, and a
model is called better or worse than the chapter's ANFIS only where the paired interval of
the difference on the same units excludes 0 (the comparison's ``verdict``); models whose
difference is not distinguishable are named as such. The caveats say what the numbers
rest on: how many independent units, which intervals could not be computed, which
numbers are in-sample.
"""

from __future__ import annotations

from pipeline.figures.headline import model_label

__all__ = ["findings"]

REFERENCE = "anfis"

#: (metric key, what it measures in a sentence, unit text, decimals)
_SENTENCES = (
    ("heldout.rssi_mae_db", "a held-out RSSI error (MAE)", " dB", 2),
    ("heldout.detection_brier", "a held-out detection Brier score", "", 3),
    ("tag_localisation.median_m", "a median error localising held-out tags", " m", 2),
    ("robot_localisation.median_m", "an RFID-only robot median error", " m", 2),
)


def _iv_text(e: dict, unit: str, digits: int) -> str:
    est = f"{e['estimate']:.{digits}f}{unit}"
    if e.get("low") is None or e.get("high") is None:
        return f"{est} (no interval: {e.get('note') or 'too few units'})"
    return f"{est} [{e['low']:.{digits}f}, {e['high']:.{digits}f}]"


def _names(models: list[str]) -> str:
    labels = [model_label(m) for m in models]
    if len(labels) <= 1:
        return "".join(labels)
    return ", ".join(labels[:-1]) + " and " + labels[-1]


def _metric_sentence(key: str, what: str, unit: str, digits: int, ivs: dict,
                     cmp_: dict) -> str | None:
    sec = ivs.get(key) or {}
    ref = (sec.get("models") or {}).get(REFERENCE)
    if not isinstance(ref, dict) or ref.get("estimate") is None:
        return None
    verdicts = cmp_.get(key) or {}
    worse = [m for m, c in verdicts.items() if (c or {}).get("verdict") == "worse"]
    better = [m for m, c in verdicts.items() if (c or {}).get("verdict") == "better"]
    same = [m for m, c in verdicts.items()
            if (c or {}).get("verdict") not in ("worse", "better", None)]
    s = (f"The chapter's FCM + ANFIS has {what} of {_iv_text(ref, unit, digits)} "
         f"over {sec.get('n_units', '?')} {sec.get('unit', 'unit')}s.")
    if ref.get("low") is None or ref.get("high") is None:
        return s + " Without an interval no model is ranked on it."
    parts = []
    if better:
        parts.append(f"{_names(better)} {'does' if len(better) == 1 else 'do'} better")
    if worse:
        parts.append(f"{_names(worse)} {'does' if len(worse) == 1 else 'do'} worse")
    if same:
        parts.append(f"{_names(same)} {'is' if len(same) == 1 else 'are'} not distinguishable "
                     "from it at 95 %")
    if parts:
        s += " On the same units, " + "; ".join(parts) + "."
    return s


def findings(metrics: dict) -> tuple[list[str], list[str]]:
    """Findings and caveats of a run, as plain sentences.

    Parameters
    ----------
    metrics : dict
        A run's ``metrics.json`` (a single study or a replicated study's pooled file).

    Returns
    -------
    findings : list of str
        Up to five sentences: per headline metric the reference model's estimate with
        its interval and which models are better, worse or not distinguishable; whether
        the robot's pose error costs the learned RSSI model anything measurable.
    caveats : list of str
        What the numbers rest on (units, intervals not computed, single run).
    """
    ivs = metrics.get("intervals") if isinstance(metrics.get("intervals"), dict) else {}
    cmp_ = ((metrics.get("comparisons") or {}).get("metrics") or {}) if isinstance(
        metrics.get("comparisons"), dict) else {}
    out, caveats = [], []
    if not ivs:
        return ([], ["This run has no intervals (an older run directory): its numbers "
                     "cannot rank the models."])
    for key, what, unit, digits in _SENTENCES:
        s = _metric_sentence(key, what, unit, digits, ivs, cmp_)
        if s:
            out.append(s)
    pose = (cmp_.get("heldout.rssi_mae_db") or {}).get("anfis_truepose")
    if isinstance(pose, dict) and pose.get("estimate") is not None and pose.get("low") is not None:
        cost = (-pose["estimate"], -pose["high"], -pose["low"])
        verdict = "costs nothing measurable" if pose.get("verdict") not in ("better", "worse") \
            else "costs a measurable amount"
        out.append(f"Training on MCL poses instead of true poses {verdict}: it changes the "
                   f"held-out RSSI MAE by {cost[0]:+.2f} dB [{cost[1]:+.2f}, {cost[2]:+.2f}].")
    units = {sec.get("unit"): sec.get("n_units") for sec in ivs.values() if isinstance(sec, dict)}
    caveats.append("Intervals resample " + ", ".join(
        f"{n} {u}s" for u, n in units.items() if u) + "; models are compared on the same "
        "units, so a difference is stated only where its paired interval excludes 0.")
    missing = sorted({model_label(m) for sec in ivs.values() if isinstance(sec, dict)
                      for m, e in (sec.get("models") or {}).items()
                      if isinstance(e, dict) and e.get("estimate") is not None
                      and e.get("low") is None})
    if missing:
        caveats.append("Some estimates have no interval (too few units, e.g. filter runs of "
                       "one study): " + ", ".join(missing[:6])
                       + (" and others" if len(missing) > 6 else "") + ".")
    if not isinstance(metrics.get("replicates"), dict):
        caveats.append("One study: its tour, MCL run and held-out layout are one draw; "
                       "`[replicates] n = 5` pools independent replicates.")
    caveats.append("Errors are against the noise-free ray-traced truth, itself uncertain "
                   "by its seed-to-seed spread (docs/physics.md); in-sample numbers further "
                   "down are labelled and optimistic.")
    return out[:5], caveats

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


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and v == v


def _iv_text(e: dict, unit: str, digits: int) -> str:
    est = f"{e['estimate']:.{digits}f}{unit}"
    if not (_is_num(e.get("low")) and _is_num(e.get("high"))):
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
    models = sec.get("models") if isinstance(sec, dict) else None
    ref = models.get(REFERENCE) if isinstance(models, dict) else None
    if not isinstance(ref, dict) or not _is_num(ref.get("estimate")):
        return None
    verdicts = cmp_.get(key) if isinstance(cmp_.get(key), dict) else {}
    v = {m: c.get("verdict") for m, c in verdicts.items() if isinstance(c, dict)}
    worse = [m for m, x in v.items() if x == "worse"]
    better = [m for m, x in v.items() if x == "better"]
    same = [m for m, x in v.items() if x == "not distinguishable at 95 %"]
    s = (f"The chapter's FCM + ANFIS has {what} of {_iv_text(ref, unit, digits)} "
         f"over {sec.get('n_units', '?')} {sec.get('unit', 'unit')}s.")
    if not (_is_num(ref.get("low")) and _is_num(ref.get("high"))):
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
    cmp_ = metrics.get("comparisons") if isinstance(metrics.get("comparisons"), dict) else {}
    cmp_ = cmp_.get("metrics") if isinstance(cmp_.get("metrics"), dict) else {}
    out, caveats = [], []
    if not ivs:
        return ([], ["This run has no intervals (an older run directory): its numbers "
                     "cannot rank the models."])
    for key, what, unit, digits in _SENTENCES:
        s = _metric_sentence(key, what, unit, digits, ivs, cmp_)
        if s:
            out.append(s)
    pose = (cmp_.get("heldout.rssi_mae_db") or {}).get("anfis_truepose")
    if isinstance(pose, dict) and all(_is_num(pose.get(k)) for k in ("estimate", "low", "high")):
        # comparisons are model minus reference: true-pose minus MCL-pose; MCL's cost is
        # the negative, with the interval mirrored
        cost, lo, hi = -pose["estimate"], -pose["high"], -pose["low"]
        verdict = pose.get("verdict")
        how = ("costs a measurable amount" if verdict == "better" else
               "measurably helps" if verdict == "worse" else "costs nothing measurable")
        out.append(f"Training on MCL poses instead of true poses {how}: it changes the "
                   f"held-out RSSI MAE by {cost:+.2f} dB [{lo:+.2f}, {hi:+.2f}].")
    units: dict[str, set] = {}
    for sec in ivs.values():
        if isinstance(sec, dict) and isinstance(sec.get("unit"), str):
            units.setdefault(sec["unit"], set()).add(sec.get("n_units"))
    counts = {u: "-".join(str(n) for n in sorted(x for x in ns if isinstance(x, int)))
              for u, ns in units.items()}
    caveats.append("Intervals resample " + ", ".join(
        f"{n} {u}s" for u, n in counts.items()) + "; models are compared on the same "
        "units, so a difference is stated only where its paired interval excludes 0.")
    missing = sorted({model_label(str(m)) for sec in ivs.values() if isinstance(sec, dict)
                      and isinstance(sec.get("models"), dict)
                      for m, e in sec["models"].items()
                      if isinstance(e, dict) and _is_num(e.get("estimate"))
                      and not _is_num(e.get("low"))})
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

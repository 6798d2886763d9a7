"""Does calibration find what was planted? A twin study with known differences, calibrated.

A simulated study of the bundled corridor is run twice: the *control* with the study's
own reader, the *planted* twin with antenna 1's cable loss +3 dB, tags 2 dB more
sensitive (``reader.tag_sensitivity_dbm`` -2 dB) and the concrete (the floor, the
construction carrying most of the traced path power) of permittivity x1.5
(``[[materials]]``: 7.86 for P.2040's 5.24). Each is exported as a recording
(:func:`pipeline.apps.export.export_csv`) and run as a recorded study with the *unchanged*
config (:mod:`pipeline.stages.calibration`); the table gives each parameter planted,
recovered with its 95 % interval, and the control's, and the held-out RSSI MAE before
and after calibration.

Two variants, one table each: the recording's poses *true* (the ray tracer then sees
exactly the links that were read: only the planted differences and the reader's noise
remain), and the robot's *MCL estimates* (as a real robot's are; ``--true-only`` skips it).

    python bench/calibration_twin.py [--true-only] [--length 10] [--out /tmp/calibration_twin]

Writes ``twin.json`` under ``--out/<variant>``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

from pipeline import runfiles

#: What the planted twin changes: (parameter, planted value of the fit).
PLANTED = {"antenna_offset_db[1]": -3.0, "tag_sensitivity_offset_db": -2.0,
           "rssi_offset_db": 0.0, "antenna_offset_db[0]": 0.0,
           "uhf-concrete-t0p200.relative_permittivity": 1.5 * 5.24}


def _study(cfg, run: Path, rec: Path, recorded: Path) -> dict:
    from pipeline.apps.export import export_csv
    from pipeline.apps.studyrun import run_full_study

    t0 = time.perf_counter()
    run_full_study(cfg, run, command_line=["bench"], upto="reads")
    export_csv(run, rec)
    return {"simulate_s": time.perf_counter() - t0}


def _recorded(base, rec: Path, out: Path) -> dict:
    from pipeline.apps.studyrun import run_full_study
    from pipeline.config import replace_path

    cfg = base
    for key, name in (("recording.tags", "tags.csv"), ("recording.poses", "poses.csv"),
                      ("recording.reads", "reads.csv")):  # reads last: it needs the tags
        cfg = replace_path(cfg, key, str(rec / name))
    t0 = time.perf_counter()
    run_full_study(cfg, out, command_line=["bench"])
    cal = json.loads((out / runfiles.CALIBRATION).read_text())
    return {"recorded_s": time.perf_counter() - t0, "calibration": cal}


def _fmt(v: dict) -> str:
    return f"{v['value']:7.3g} [{v['low']:6.3g}, {v['high']:6.3g}]"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--true-only", action="store_true", help="only the variant with true poses")
    ap.add_argument("--length", type=float, default=10.0, help="tour length [m]")
    ap.add_argument("--out", type=Path, default=Path("/tmp/calibration_twin"))
    args = ap.parse_args()
    for mcl in (False,) if args.true_only else (False, True):
        twin(args.out / ("mcl" if mcl else "true_poses"), mcl=mcl, length_m=args.length)


def twin(out: Path, *, mcl: bool, length_m: float) -> dict:
    """One variant: the control and the planted twin, simulated, exported, calibrated."""
    from pipeline.config import MaterialConfig, load_config, replace_path

    root = Path(__file__).resolve().parents[1]
    base = load_config(root / "configs" / "tiny.toml")
    base = replace_path(base, "tour.max_length_m", length_m)
    base = replace_path(base, "tracing.cache_dir", str(out / "cache"))
    if not mcl:
        base = replace_path(base, "localisation.enabled", False)
    ants = list(base.robot.antennas)
    ants[1] = dataclasses.replace(ants[1], cable_loss_db=3.0)
    planted = dataclasses.replace(base, robot=dataclasses.replace(base.robot, antennas=tuple(ants)))
    planted = replace_path(planted, "reader.tag_sensitivity_dbm", base.reader.tag_sensitivity_dbm - 2.0)
    planted = dataclasses.replace(planted, materials=(MaterialConfig(
        name="concrete", relative_permittivity=PLANTED["uhf-concrete-t0p200.relative_permittivity"]),))
    res = {}
    for name, cfg in (("control", base), ("planted", planted)):
        d = out / name
        res[name] = _study(cfg, d / "sim", d / "rec", d / "recorded")
        res[name].update(_recorded(base, d / "rec", d / "recorded"))
    print(f"\ncalibration twin ({'MCL poses' if mcl else 'true poses'}, {length_m} m of corridor)")
    print(f"{'parameter':42s} {'planted':>8s}  {'recovered [95 %]':>24s}  {'control [95 %]':>24s}")
    cp, pp = res["control"]["calibration"]["parameters"], res["planted"]["calibration"]["parameters"]
    for key in pp:
        want = PLANTED.get(key, pp[key].get("traced"))  # an unplanted construction: as traced
        plant = f"{want:8.3g}" if want is not None else " " * 8
        print(f"{key:42s} {plant}  {_fmt(pp[key]):>24s}  {_fmt(cp.get(key, pp[key])):>24s}")
    for name in ("control", "planted"):
        cal = res[name]["calibration"]
        h = cal["heldout"]["rssi_mae_db"]
        print(f"{name}: held-out RSSI MAE before {h['before']['estimate']:.2f} dB, after "
              f"{h['after']['estimate']:.2f} dB ({h['difference']['verdict']}; {h['n_tags']} tags); "
              f"simulate {res[name]['simulate_s']:.0f} s, recorded study {res[name]['recorded_s']:.0f} s")
        for where in ("crossvalidated", "heldout"):  # the choice (training tags), its check
            vs = cal.get("constructions", {}).get(f"{where}_against_reader_only", {}).get("rssi_mae_db")
            if vs:
                print(f"  constructions fitted against the reader alone ({where}): RSSI MAE "
                      f"{vs['with_constructions']['estimate']:.2f} vs {vs['reader_only']['estimate']:.2f} dB "
                      f"({vs['difference']['verdict']}); in calibrated.toml: "
                      f"{cal['constructions'].get('in_calibrated_toml') is True}")
    (out / "twin.json").write_text(json.dumps(res, indent=1, default=str))
    return res


if __name__ == "__main__":
    main()

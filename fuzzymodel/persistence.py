"""Human-readable JSON files for fuzzy models; atomic writes, strict reads.

An ANFIS file lists the inputs (name, normalisation, membership functions),
the rules (one antecedent MF per input, consequent coefficients) and the
provenance. Parameters are stored in normalised input units
``u = (x - offset) / scale``, which is what :meth:`ANFIS.load` reads; the same
parameters converted to input units are written alongside
(``*_in_input_units``) for people and are ignored on load.
"""

from __future__ import annotations

import json
import os
import tempfile
from importlib import metadata
from pathlib import Path

import numpy as np

from .errors import FuzzyModelFileError
from .initfis import Premise
from .membership import MF_PARAM_NAMES

__all__ = [
    "ANFIS_FORMAT",
    "anfis_kwargs_from_dict",
    "anfis_to_dict",
    "package_version",
    "read_json",
    "require_keys",
    "write_json",
]

#: Format tag written to (and required in) every ANFIS file.
ANFIS_FORMAT = "rfidstudy.fuzzymodel.anfis/1"

#: Provenance keys that hold wall-clock times; not written (files must be reproducible).
_TIME_KEYS = frozenset({"date_utc"})


def _without_times(obj):
    """``obj`` with every key of :data:`_TIME_KEYS` dropped, at any depth."""
    if isinstance(obj, dict):
        return {k: _without_times(v) for k, v in obj.items() if k not in _TIME_KEYS}
    if isinstance(obj, list):
        return [_without_times(v) for v in obj]
    return obj


def package_version() -> str:
    """Installed version of the ``rfidstudy`` distribution, or ``"unknown"``."""
    try:
        return metadata.version("rfidstudy")
    except metadata.PackageNotFoundError:
        return "unknown"


def write_json(path, obj: dict) -> Path:
    """Write `obj` as indented JSON to a temporary name, then rename into place."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(obj, fh, indent=2, allow_nan=False)
            fh.write("\n")
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def read_json(path) -> dict:
    """Read a JSON object; errors name the file."""
    path = Path(path)
    try:
        with open(path, encoding="utf-8") as fh:
            obj = json.load(fh)
    except OSError as exc:
        raise FuzzyModelFileError(f"{path}: cannot read: {exc}") from exc
    except json.JSONDecodeError as exc:
        raise FuzzyModelFileError(f"{path}: not valid JSON: {exc}") from exc
    if not isinstance(obj, dict):
        raise FuzzyModelFileError(f"{path}: top level must be a JSON object")
    return obj


def require_keys(d, required: set, optional: set, where: str) -> None:
    """Raise naming `where` and the key if `d` lacks a required or has an unknown key."""
    if not isinstance(d, dict):
        raise FuzzyModelFileError(f"{where}: expected a JSON object, got {type(d).__name__}")
    missing = sorted(required - d.keys())
    if missing:
        raise FuzzyModelFileError(f"{where}: missing key {missing[0]!r}")
    unknown = sorted(d.keys() - required - optional)
    if unknown:
        raise FuzzyModelFileError(f"{where}: unknown key {unknown[0]!r}")


def _mf_name(i_local: int) -> str:
    return f"mf{i_local}"


def anfis_to_dict(model) -> dict:
    """JSON-ready description of an :class:`ANFIS` (see module doc)."""
    prem = model.premise
    names = MF_PARAM_NAMES[prem.mf_type]
    local = np.zeros(prem.mf_input.size, dtype=int)
    inputs = []
    for i, name in enumerate(model.input_names):
        idx = np.flatnonzero(prem.mf_input == i)
        local[idx] = np.arange(idx.size)
        off, sc = float(model.input_offset[i]), float(model.input_scale[i])
        mfs = []
        for k, j in enumerate(idx):
            p = dict(zip(names, map(float, prem.mf_params[j]), strict=True))
            phys = dict(p)
            phys["c"] = off + sc * p["c"]
            phys[names[0]] = sc * abs(p[names[0]])
            mfs.append({"name": _mf_name(k), "params": p, "params_in_input_units": phys})
        inputs.append({"name": name, "offset": off, "scale": sc, "mfs": mfs})
    rules = []
    for r in range(model.n_rules):
        coef = model.consequents[r]
        p, q = coef[:-1], float(coef[-1])
        p_phys = p / model.input_scale
        rules.append({
            "if": {model.input_names[i]: _mf_name(int(local[prem.rules[r, i]]))
                   for i in range(model.n_inputs)},
            "then": {"coefficients": p.tolist(), "constant": q},
            "then_in_input_units": {
                "coefficients": p_phys.tolist(),
                "constant": q - float(p_phys @ model.input_offset),
            },
        })
    return {
        "format": ANFIS_FORMAT,
        "description": (
            "First-order Takagi-Sugeno fuzzy system (ANFIS, Jang 1993). "
            "u_i = (x_i - offset_i) / scale_i; MF params and 'then' are in u; "
            "output = sum_r wbar_r * (coefficients . u + constant)."
        ),
        "mf_type": prem.mf_type,
        "mf_param_names": list(names),
        "inputs": inputs,
        "output": model.output_name,
        "rules": rules,
        "provenance": _without_times(model.provenance),
    }


def anfis_kwargs_from_dict(d: dict, source: str) -> dict:
    """Constructor keyword arguments of :class:`ANFIS` from :func:`anfis_to_dict` output.

    Raises
    ------
    FuzzyModelFileError
        Naming `source` and the offending key or value.
    """
    top = {"format", "mf_type", "inputs", "output", "rules"}
    require_keys(d, top, {"description", "mf_param_names", "provenance"}, source)
    if d["format"] != ANFIS_FORMAT:
        raise FuzzyModelFileError(f"{source}: format {d['format']!r}, expected {ANFIS_FORMAT!r}")
    mf_type = d["mf_type"]
    if mf_type not in MF_PARAM_NAMES:
        raise FuzzyModelFileError(f"{source}: unknown mf_type {mf_type!r}")
    names = MF_PARAM_NAMES[mf_type]
    mf_input, params, offsets, scales, input_names, lookup = [], [], [], [], [], []
    for i, inp in enumerate(d["inputs"]):
        where = f"{source}: inputs[{i}]"
        require_keys(inp, {"name", "offset", "scale", "mfs"}, set(), where)
        input_names.append(inp["name"])
        offsets.append(inp["offset"])
        scales.append(inp["scale"])
        table = {}
        for k, mf in enumerate(inp["mfs"]):
            w = f"{where}.mfs[{k}]"
            require_keys(mf, {"name", "params"}, {"params_in_input_units"}, w)
            require_keys(mf["params"], set(names), set(), f"{w}.params")
            table[mf["name"]] = len(params)
            mf_input.append(i)
            params.append([float(mf["params"][n]) for n in names])
        lookup.append(table)
    rules, cons = [], []
    for r, rule in enumerate(d["rules"]):
        where = f"{source}: rules[{r}]"
        require_keys(rule, {"if", "then"}, {"then_in_input_units"}, where)
        require_keys(rule["if"], set(input_names), set(), f"{where}.if")
        require_keys(rule["then"], {"coefficients", "constant"}, set(), f"{where}.then")
        row = []
        for i, name in enumerate(input_names):
            mf = rule["if"][name]
            if mf not in lookup[i]:
                raise FuzzyModelFileError(f"{where}.if: input {name!r} has no MF {mf!r}")
            row.append(lookup[i][mf])
        rules.append(row)
        coef = list(rule["then"]["coefficients"])
        if len(coef) != len(input_names):
            raise FuzzyModelFileError(f"{where}.then.coefficients: expected {len(input_names)}")
        cons.append(coef + [rule["then"]["constant"]])
    if not rules:
        raise FuzzyModelFileError(f"{source}: rules is empty")
    arr = np.asarray(params, dtype=np.float64)
    if not np.all(np.isfinite(arr)) or not np.all(np.isfinite(np.asarray(cons, dtype=float))):
        raise FuzzyModelFileError(f"{source}: non-finite parameter")
    return {
        "premise": Premise(mf_type, np.asarray(mf_input), arr, np.asarray(rules)),
        "consequents": np.asarray(cons, dtype=np.float64),
        "input_offset": np.asarray(offsets, dtype=np.float64),
        "input_scale": np.asarray(scales, dtype=np.float64),
        "input_names": input_names,
        "output_name": d["output"],
        "provenance": d.get("provenance", {}),
    }

"""Whether a study's settings are smoke-scale: numbers that measure cost, not accuracy.

The bundled smoke configs (``configs/tiny.toml``, ``configs/warehouse.toml``, ...) trace
with few rays and train for a few epochs, so a run finishes in minutes; their held-out
scores are not meaningful. A report or figure made from such a run must say so where a
reader looks: :func:`smoke_scale_reasons` names each setting below its limit, the report
opens with them (:func:`pipeline.report.html.write_report`) and every figure carries a banner
(:func:`pipeline.figures.drawall.draw_all`).

The limits sit well below the default study's values (10,000 of 30,000 rays, depth 3 of
5, 20 of 100 epochs): ray counts under 10,000 flip read decisions of links near the threshold
(docs/maps.md, "What each tracer is worth": 2,000 rays flip 1.6 per position against
0.2-0.3 with 32,000), depth under 3 drops the twice-reflected paths shelf tags see, and
ANFIS under 20 epochs has not left its initial partition (bench/anfis.py).
"""

from __future__ import annotations

__all__ = ["SMOKE_LIMITS", "smoke_banner", "smoke_scale_reasons"]

#: (section, key, smallest value of a full-scale study, what it is).
SMOKE_LIMITS = (
    ("tracing", "samples_per_src", 10_000, "rays per antenna position"),
    ("tracing", "max_depth", 3, "interactions per path"),
    ("training", "epochs", 20, "ANFIS epochs"),
)


def smoke_scale_reasons(cfg: dict) -> list[str]:
    """The settings of a resolved config (a ``config.toml`` as a dict) below full scale.

    Returns
    -------
    list of str
        ``"tracing.samples_per_src = 2000 (< 10000 rays per antenna position)"`` per setting;
        empty for a full-scale study or a config that does not hold the key.
    """
    out = []
    for section, key, limit, what in SMOKE_LIMITS:
        value = (cfg.get(section) or {}).get(key)
        if isinstance(value, int | float) and not isinstance(value, bool) and value < limit:
            out.append(f"{section}.{key} = {value} (< {limit} {what})")
    return out


def smoke_banner(cfg: dict) -> str:
    """One line for a figure or a report's top, or "" for a full-scale study."""
    reasons = smoke_scale_reasons(cfg)
    if not reasons:
        return ""
    return "SMOKE-SCALE SETTINGS, not for conclusions: " + "; ".join(reasons)

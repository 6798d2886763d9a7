"""What ``rfidstudy run TARGET`` means: a study TOML, a map, a scene, or the default study.

:func:`resolve_target` turns the command line's target, ``--set KEY=VALUE`` overrides and
``--backend`` into a :class:`~pipeline.config.StudyConfig` (the CLI re-exports it).
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from pipeline.apps.profiles import load_profile
from pipeline.config import ConfigError, StudyConfig, config_from_mapping
from scenes.sources import source_of_file

__all__ = ["resolve_target"]

_STUDY_KEYS = set(StudyConfig.__dataclass_fields__)


def _parse_value(text: str):
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def resolve_target(target: str | None, overrides: list[str] | None = None,
                   backend: str | None = None) -> StudyConfig:
    """Turn ``run``'s argument into a study config.

    Parameters
    ----------
    target : str or None
        ``None``: the default study; a study TOML (a file whose top-level keys are study
        keys); a file of a scene source with a run profile
        (:attr:`scenes.sources.SceneSource.run_profile`: a map_server YAML, the default
        study with :func:`pipeline.apps.profiles.map_scale_profile` on top); otherwise a
        scene: a bundled name, a scene.toml or a file a scene source reads.
    overrides : list of str
        ``KEY=VALUE`` with dotted study keys (``training.epochs=10``); VALUE in TOML syntax.
    backend : str, optional
        Overrides ``tracing.backend``.
    """
    data: dict = {}
    source, base_dir = "<default>", None
    if target:
        p = Path(target)
        scene_source = source_of_file(p)
        if p.suffix == ".toml" and p.is_file():
            try:
                parsed = tomllib.loads(p.read_text(encoding="utf-8"))
            except tomllib.TOMLDecodeError as exc:
                raise ConfigError(f"{p}: invalid TOML: {exc}") from None
            if set(parsed) & _STUDY_KEYS:
                data, source, base_dir = parsed, str(p), p.parent
            else:
                data = {"scene": str(p.resolve())}
        elif (p.suffix == ".toml" or scene_source is not None) and not p.exists():
            raise ConfigError(f"{p}: no such file")
        elif scene_source is not None and scene_source.run_profile:  # a map alone: map-scale

            name = scene_source.run_profile
            data = {**load_profile(name), "scene": str(p.resolve())}
            source = f"{p} with the {name.replace('_', '-')} profile (pipeline/apps/profiles/{name}.toml)"
        else:
            data = {"scene": str(p.resolve()) if p.exists() else target}
    for ov in overrides or []:
        key, eq, val = ov.partition("=")
        if not eq:
            raise ConfigError(f"--set {ov!r}: expected KEY=VALUE")
        cur = data
        parts = key.strip().split(".")
        for part in parts[:-1]:
            cur = cur.setdefault(part, {})
            if not isinstance(cur, dict):
                raise ConfigError(f"--set {ov!r}: {part} is not a table")
        cur[parts[-1]] = _parse_value(val.strip())
    if backend:
        data.setdefault("tracing", {})["backend"] = backend
    return config_from_mapping(data, source=source, base_dir=base_dir)

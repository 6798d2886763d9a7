"""A smoke-scale run says so on its report and on every figure; a full-scale config does not."""

from __future__ import annotations

import tomllib

import numpy as np
from PIL import Image

from pipeline.report.smokescale import smoke_banner, smoke_scale_reasons
from tests.conftest import ROOT, copy_run


def _as_dict(path):
    return tomllib.loads(path.read_text())


def test_bundled_smoke_configs_are_smoke_scale_and_the_default_is_not(tmp_path):
    tiny = _as_dict(ROOT / "configs" / "tiny.toml")
    reasons = smoke_scale_reasons(tiny)
    assert any(r.startswith("tracing.samples_per_src = 2000") for r in reasons)
    assert any(r.startswith("training.epochs = 3") for r in reasons)
    # the default study (every key at its default) is full scale
    from pipeline.config import StudyConfig, config_to_toml

    default = tomllib.loads(config_to_toml(StudyConfig()))
    assert smoke_scale_reasons(default) == [] and smoke_banner(default) == ""
    # the bundled warehouse configs are smoke-scale too (2,000 rays, depth 2, 3 epochs)
    for name in ("warehouse.toml", "warehouse_large.toml"):
        assert len(smoke_scale_reasons(_as_dict(ROOT / "configs" / name))) == 3


def test_report_and_figures_of_a_smoke_run_carry_the_banner(tiny_study, tmp_path):
    from pipeline.figures import draw_all
    from pipeline.report.html import write_report

    run = copy_run(tiny_study, tmp_path / "run")
    html = write_report(run, embed=False).read_text()
    assert "Smoke-scale settings" in html and "tracing.samples_per_src = 2000" in html
    # a figure drawn with the banner differs from the same figure drawn without it only in
    # a red band at its top
    out_b, out_n = tmp_path / "b", tmp_path / "n"
    draw_all(run, out_b, names=["scene_top_view"], workers=1)
    cfg = run / "config.toml"
    text = cfg.read_text()
    cfg.write_text(text.replace("samples_per_src = 2000", "samples_per_src = 30000")
                   .replace("max_depth = 2", "max_depth = 5").replace("epochs = 3", "epochs = 100"))
    draw_all(run, out_n, names=["scene_top_view"], workers=1)
    a = np.asarray(Image.open(next(out_b.glob("*.png"))).convert("RGB")).astype(int)
    b = np.asarray(Image.open(next(out_n.glob("*.png"))).convert("RGB")).astype(int)
    # the banner adds a band above the figure (0.22 in at the PNG's dpi) holding red text,
    # where the figure without it has its title: no red
    band = a.shape[0] - b.shape[0]
    assert a.shape[1] == b.shape[1] and 20 <= band <= 40
    red = lambda img: (img[..., 0] > 150) & (img[..., 1] < 80) & (img[..., 2] < 80)  # noqa: E731
    assert red(a[:band]).sum() > 50 and red(b[:band]).sum() < 10  # b: a title, no red

"""Figures for a paper: formats, resolution, a subset, TrueType fonts; runs side by side.

On the session's tiny study (real models, metrics with intervals, downstream files).
"""

from __future__ import annotations

import re
import shutil

import numpy as np
import pandas as pd
import pytest
from PIL import Image
from typer.testing import CliRunner

from pipeline.apps.cli import app
from pipeline.figures import FigureOutput, draw_all
from pipeline.figures.headline import HEADLINE_METRICS, headline_table
from tests.conftest import copy_run

runner = CliRunner()


def _font_subtypes(pdf: bytes) -> set[str]:
    """The /Subtype of every font dictionary of a PDF matplotlib wrote (its font objects
    are not in compressed object streams)."""
    subtypes = set()
    for m in re.finditer(rb"/Type\s*/Font\b(.*?)>>", pdf, flags=re.S):
        st = re.search(rb"/Subtype\s*/(\w+)", m.group(1))
        if st:
            subtypes.add(st.group(1).decode())
    return subtypes


def test_the_font_check_sees_type3_in_matplotlibs_default(tmp_path):
    # the check itself can fail: a PDF written with matplotlib's default fonttype 3
    import matplotlib as mpl
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure()
    FigureCanvasAgg(fig)
    fig.subplots().set_title("Type 3 by default")
    with mpl.rc_context({"pdf.fonttype": 3}):
        fig.savefig(tmp_path / "t3.pdf")
    assert "Type3" in _font_subtypes((tmp_path / "t3.pdf").read_bytes())


def test_figures_cli_writes_pdf_with_truetype_fonts_at_the_asked_dpi(tiny_study, tmp_path):
    run = copy_run(tiny_study, tmp_path / "run")
    before = {p.name: p.read_bytes() for p in (run / "figures").iterdir()}
    res = runner.invoke(app, ["figures", str(run), "--format", "pdf,png", "--dpi", "300",
                              "--only", "baselines,mcl_error"])
    assert res.exit_code == 0, res.output
    out = run / "paper_figures"
    assert sorted(p.name for p in out.iterdir()) == [
        "baselines.pdf", "baselines.png", "mcl_error.pdf", "mcl_error.png"]
    for name in ("baselines", "mcl_error"):
        fonts = _font_subtypes((out / f"{name}.pdf").read_bytes())
        assert "Type3" not in fonts and fonts, fonts  # Type 42: Type0 + CIDFontType2
        with Image.open(out / f"{name}.png") as im:
            dpi = im.info["dpi"][0]
        assert abs(dpi - 300) < 1, dpi
    # the study's own figures (hashed by its stage record) are untouched
    assert {p.name: p.read_bytes() for p in (run / "figures").iterdir()} == before


def test_figures_cli_refuses_bad_options(tiny_study, tmp_path):
    run = copy_run(tiny_study, tmp_path / "run")
    for args, words in ((["--format", "jpg"], "jpg"), (["--dpi", "5"], "dpi"),
                        (["--only", "nope"], "nope"),
                        (["--dpi", "300", "--out", str(run / "figures")], "figures/")):
        res = runner.invoke(app, ["figures", str(run), *args])
        assert res.exit_code == 2 and words in res.output, (args, res.output)


def test_draw_all_default_output_is_the_runs_own_else_png_and_pdf_at_120_dpi(tiny_study,
                                                                             tmp_path):
    import tomllib

    import tomli_w

    # the run's [figures] (configs/tiny.toml: PNG alone), as its figures stage drew them
    paths = draw_all(tiny_study.run, out_dir=tmp_path / "own", names=["baselines"], workers=1)
    assert [p.name for p in paths] == ["baselines.png"]
    # a run of a version before [figures]: PNG and PDF at 120 dpi
    run = copy_run(tiny_study, tmp_path / "old", ignore=shutil.ignore_patterns("figures"))
    cfg = tomllib.loads((run / "config.toml").read_text())
    del cfg["figures"]
    (run / "config.toml").write_text(tomli_w.dumps(cfg))
    paths = draw_all(run, out_dir=tmp_path / "old_figs", names=["baselines"], workers=1)
    assert [p.name for p in paths] == ["baselines.png", "baselines.pdf"]
    with Image.open(paths[0]) as im:
        assert abs(im.info["dpi"][0] - 120) < 1
    # a [figures] that names no output stops the redraw, naming the file
    cfg["figures"] = {"formats": ["png", "png"]}
    (run / "config.toml").write_text(tomli_w.dumps(cfg))
    with pytest.raises(ValueError, match=r"config.toml: \[figures\]"):
        draw_all(run, out_dir=tmp_path / "bad", names=["baselines"], workers=1)
    with pytest.raises(ValueError, match="formats"):
        FigureOutput(formats=("png", "png"))


def test_headline_table_carries_intervals_and_verdicts(tiny_study):
    t = headline_table(tiny_study.run)
    assert set(t["metric"]) <= {m.key for m in HEADLINE_METRICS}
    anfis = t[(t["metric"] == "heldout.rssi_mae_db") & (t["model"] == "anfis")].iloc[0]
    assert anfis["low"] <= anfis["estimate"] <= anfis["high"]
    others = t[(t["model"] != "anfis") & (t["metric"] == "heldout.rssi_mae_db")]
    assert set(others["verdict"]) <= {"better", "worse", "not distinguishable at 95 %"}
    assert len(others)


def test_compare_draws_runs_side_by_side(tiny_study, tmp_path):
    a = copy_run(tiny_study, tmp_path / "a")
    b = copy_run(tiny_study, tmp_path / "b")
    res = runner.invoke(app, ["compare", str(a), str(b), "--out", str(tmp_path / "cmp"),
                              "--format", "pdf"])
    assert res.exit_code == 0, res.output
    table = pd.read_csv(tmp_path / "cmp" / "compare.csv")
    assert set(table["run"]) == {"a", "b"}
    # the same run twice: the same numbers side by side
    wide = table.pivot_table(index=["metric", "model"], columns="run", values="estimate")
    np.testing.assert_array_equal(wide["a"].to_numpy(), wide["b"].to_numpy())
    assert "Type3" not in _font_subtypes((tmp_path / "cmp" / "compare.pdf").read_bytes())
    bad = runner.invoke(app, ["compare", str(a), "--out", str(a / "cmp")])
    assert bad.exit_code == 2 and "inside the run directory" in bad.output


def test_figures_and_compare_never_overwrite_a_users_file(tiny_study, tmp_path):
    """As git with an untracked file: --out into a folder of the user's (not empty, no
    marker of the tool's) is refused and the user's files are unchanged; the tool's own
    folder is written again; another run's folders are never an --out."""
    run = copy_run(tiny_study, tmp_path / "run")
    user = tmp_path / "paper"
    user.mkdir()
    (user / "baselines.pdf").write_bytes(b"my figure")
    (user / "compare.csv").write_bytes(b"my table")
    for args in (["figures", str(run), "--only", "baselines", "--out", str(user)],
                 ["compare", str(run), "--out", str(user)]):
        res = runner.invoke(app, args)
        assert res.exit_code == 2 and "not a" in res.output and "rfidstudy" in res.output, res.output
    assert (user / "baselines.pdf").read_bytes() == b"my figure"
    assert (user / "compare.csv").read_bytes() == b"my table"
    # a new folder becomes the tool's; a rerun may rewrite what it wrote there
    mine = tmp_path / "figs"
    for _ in range(2):
        res = runner.invoke(app, ["figures", str(run), "--only", "baselines", "--out", str(mine)])
        assert res.exit_code == 0, res.output
    # ... but not a file the user put there since
    (mine / "baselines.svg").write_bytes(b"mine too")
    res = runner.invoke(app, ["figures", str(run), "--only", "baselines", "--format", "svg",
                              "--out", str(mine)])
    assert res.exit_code == 2 and "baselines.svg" in res.output
    assert (mine / "baselines.svg").read_bytes() == b"mine too"
    # another run's folders belong to that run
    other = copy_run(tiny_study, tmp_path / "other")
    for target in (other, other / "figures", other / "stages"):
        res = runner.invoke(app, ["compare", str(run), "--out", str(target)])
        assert res.exit_code == 2 and "inside the run directory" in res.output, (target, res.output)

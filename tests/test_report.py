"""The report sections on a fixture results folder: every section builds from summary.json, the
stage files and the config; images are the files the stages write; experiment figures in the
text come from the config; the notebook holds only calls."""
from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from ssamb.io import save_npz
from ssamb.report import sections
from ssamb.report.build import make_notebook
from ssamb.report.context import load_context
from ssamb.report.elements import Image, Section, Table

ROOT = Path(__file__).resolve().parent.parent
FIX = ROOT / "tests" / "data" / "report_fixture"
#: PNG files the stages write (the report may show only these)
STAGE_PNGS = (["model/fig4.png", "validation/fig9.png"]
              + [f"ident/{s}_{k}.png" for s in ("plant", "amplifier", "selfsensing") for k in ("orders", "validation")]
              + [f"uncertainty/{s}_fig7.png" for s in ("plant", "amplifier", "selfsensing")]
              + [f"mu/{c}_fig8.png" for c in ("selfsensing", "amplifier", "plant", "all")]
              + [f"closeloop/{f}.png" for f in ("calibration", "features", "residual_time", "residual_spectra",
                                               "evidence", "sensor_ratio")]
              + [f"rigs/toy/{f}.png" for f in ("holdout_c", "holdout_spectra", "agreement")])


def _sim_npz(path: Path, n: int = 400) -> None:
    t = np.arange(n) / 83300.0
    y = 1e-6 * np.sin(2 * np.pi * 20 * t)
    arrays = {"t": t, "fs_hz": 83300.0, "y_true": y, "x_true": 0 * t, "y_meas": y, "y_ss": 1.01 * y,
              "i_ypos": 3.5 + 0 * t, "i_yneg": 2.5 + 0 * t}
    save_npz(path, arrays, {"selfsensing_calibration": {"gain": 1.02, "offset_m": 1e-7},
                            "equilibrium": {"u_y": 0.61}})


def _results(tmp_path: Path, config: dict) -> Path:
    res = tmp_path / "results"
    (res / "sim").mkdir(parents=True)
    shutil.copy(FIX / "summary.json", res / "summary.json")
    for name in ("levitate", config["uncertainty"]["experiment"]):
        _sim_npz(res / "sim" / f"{name}.npz")
    for p in STAGE_PNGS:
        (res / p).parent.mkdir(parents=True, exist_ok=True)
        (res / p).write_bytes(b"\x89PNG\r\n\x1a\n")
    shutil.copy(FIX / "closeloop.json", res / "closeloop" / "closeloop.json")
    shutil.copy(FIX / "rig_closeloop.json", res / "rigs" / "toy" / "closeloop.json")
    return res


@pytest.fixture()
def ctx(tmp_path):
    cfg_path = tmp_path / "config.yaml"
    shutil.copy(ROOT / "config.yaml", cfg_path)
    cfg = yaml.safe_load(cfg_path.read_text())
    return load_context(_results(tmp_path, cfg), cfg_path, tmp_path / "results" / "closeloop")


def test_every_section_builds_with_consistent_tables_and_stage_images(ctx):
    allowed = {(ctx.results / p).resolve() for p in STAGE_PNGS}
    for name in sections.ORDER:
        sec = getattr(sections, name)(ctx)
        assert isinstance(sec, Section) and sec.title, name
        for item in sec.items:
            if isinstance(item, Table):
                assert all(len(r) == len(item.header) for r in item.rows), (name, item.header)
            if isinstance(item, Image):
                assert Path(item.path).resolve() in allowed, (name, item.path)


def test_comparison_quotes_the_paper_and_reads_ours(ctx):
    tab = sections.comparison(ctx).tables()[0]
    fit_y = next(r for r in tab.rows if r[0].startswith("closed-loop LTI fit, y"))
    assert tab.header[:3] == ["quantity", "paper", "ours"] and tab.header[-1] == "why (computed)"
    assert fit_y[1] == "50.76 %" and len(fit_y) == len(tab.header)
    assert fit_y[2] == f"{ctx.summary['fit_pct']['y']:.4g} %"


def test_experiment_figures_in_the_text_come_from_the_config(tmp_path):
    """Change every experiment figure the report text mentions; the text follows, the old
    figures are gone (none is typed in)."""
    cfg_path = tmp_path / "config.yaml"
    cfg = yaml.safe_load((ROOT / "config.yaml").read_text())
    ms = cfg["experiments"][cfg["uncertainty"]["experiment"]]["excitation"]
    ms.update(amplitude_m=1.23e-4, f_min_hz=7.0, f_max_hz=31.0)
    cfg["uncertainty"]["tol_db"] = 2.5
    cfg["controller"]["fs_hz"] = 83200.0
    cfg["table1"]["f_pwm_hz"] = 31000.0
    pul = cfg["experiments"][cfg["identification"]["estimation"]]["excitation"]
    pul["amplitude_a"] = 0.37
    cfg_path.write_text(yaml.safe_dump(cfg))
    c = load_context(_results(tmp_path, cfg), cfg_path)
    text = "\n".join(getattr(sections, n)(c).text() for n in ("overview", "simulation", "identification",
                                                              "uncertainty"))
    for new in ("123 µm", "7–31 Hz", "2.5 dB", "83.2 kHz", "31 kHz", "0.37 A"):
        assert new in text, new
    for old in ("100 µm", "5–26 Hz", "3 dB", "83.3 kHz", "30 kHz", "0.3 A"):
        assert old not in text, old


def test_notebook_cells_only_call_sections(ctx):
    nb = make_notebook(ctx.results, ctx.config_path, ctx.closeloop_dir)
    for cell in nb.cells[1:]:
        assert cell.cell_type == "code"
        assert re.fullmatch(r"sec = sections\.\w+\(ctx\)\nif sec is not None:\n    show\(sec\)", cell.source)
    assert len(nb.cells) == 1 + len(sections.ORDER)


def test_failed_paper_variant_is_reported_as_failed(ctx):
    s = json.loads((ctx.results / "summary.json").read_text())
    s["details"]["identification"]["amplifier"]["paper_variant"] = {"variant": "full", "failed": True,
                                                                    "error": "LinAlgError: singular"}
    (ctx.results / "summary.json").write_text(json.dumps(s))
    c = load_context(ctx.results, ctx.config_path)
    tab = sections.identification(c).tables()[1]
    row = next(r for r in tab.rows if r[0] == "amplifier")
    assert row[-1].startswith("failed: LinAlgError")


def test_first_page_is_the_paper_against_ours_and_its_four_figures(ctx):
    assert sections.ORDER[:3] == ("overview", "comparison", "figures")
    figs = sections.figures(ctx).images()
    assert [str(Path(i.path).relative_to(ctx.results)) for i in figs] == [
        "model/fig4.png", "uncertainty/selfsensing_fig7.png", "mu/selfsensing_fig8.png", "validation/fig9.png"]
    assert [i.caption.split(":")[0] for i in figs] == ["Fig. 4", "Fig. 7", "Fig. 8", "Fig. 9"]


def test_configuration_is_a_folded_appendix_at_the_end(ctx):
    from ssamb.report.render import section_html

    assert sections.ORDER[-1] == "parameters"
    sec = sections.parameters(ctx)
    assert sec.collapsed and sec.title.startswith("Appendix")
    page = section_html(sec)
    assert page.startswith("<details>") and page.endswith("</details>") and "table1" not in sec.title
    assert "mass_kg" in page


def test_a_failure_is_reported_once_at_the_stage_where_it_began(ctx):
    reason = "no stable assembled loop among 448 combinations of the candidates"
    chain = f"Failed: r/select/plant.npz: stage select failed: {reason}"
    failed = {"select": f"select: {reason}", "assemble": f"assemble: {chain}"}
    failed.update({f"mu/{c}": f"mu: Failed: r/assemble.json: stage assemble failed: {chain}"
                   for c in ("selfsensing", "amplifier", "plant", "all")})
    s = json.loads((ctx.results / "summary.json").read_text())
    s["paper_way"] = {**(s.get("paper_way") or {}), "failed": failed}
    (ctx.results / "summary.json").write_text(json.dumps(s))
    sec = sections.paper_way(load_context(ctx.results, ctx.config_path))
    cells = [str(c) for t in sec.tables() for r in t.rows for c in r] + [sec.text()]
    assert sum(c.count(reason) for c in cells) == 1
    line = next(c for c in cells if reason in c)
    assert line.startswith("stage select failed") and "mu/all" in line and "assemble" in line


def test_provenance_names_the_code_and_every_package_version(ctx):
    rows = sections.provenance(ctx).tables()[0].rows
    info = dict((str(k), v) for k, v in rows)
    assert info["ssamb code"].startswith(("git ", "sha256 "))
    assert all(v not in (None, "", "unknown") for v in info.values()), info
    assert {"python", "numpy", "sippy_unipi", "control", "snakemake"} <= set(info)


def test_provenance_lists_exactly_the_declared_dependencies():
    import re as _re
    import tomllib

    from ssamb.provenance import DEPENDENCIES

    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    assert sorted(DEPENDENCIES) == sorted(_re.split(r"[<>=!~ ;\[]", d, 1)[0].lower() for d in declared)


def test_an_archive_without_git_is_named_by_its_sources_hash(tmp_path):
    from ssamb.provenance import source_hash, source_revision

    (tmp_path / "a.py").write_text("x = 1\n")
    first = source_hash(tmp_path)
    (tmp_path / "a.py").write_text("x = 2\n")
    assert source_hash(tmp_path) != first and len(first) == 64
    assert source_revision(tmp_path).startswith(("git ", "sha256 "))


def test_rig_section_lists_recordings_agreement_and_held_out_errors(ctx):
    """The real-rig section: parameters per recording with their agreement, the held-out errors per
    recording and channel, the effects with their held-out verdict, the physical checks."""
    sec = sections.rigs(ctx)
    heads = [t.header[0] for t in sec.tables()]
    assert heads[:2] == ["parameter", "recording"]
    par = sec.tables()[0]
    assert par.rows[0][0] == "plant.b_gain" and "agree" in par.rows[0][-1]
    err = sec.tables()[1]
    assert {r[1] for r in err.rows} == {"y", "u"} and any(r[0] == "all held out" for r in err.rows)
    assert any(t.header[0] == "effect" and t.rows[0][0] == "bias" for t in sec.tables())


def test_the_rig_section_lists_the_joint_calibration_identified_or_not():
    """The combined model's table holds every shared parameter of the joint calibration, identified
    or not, beside each recording's own calibrated value, and says where it started and whether
    it stopped short."""
    from ssamb.report.sections.rigs import _joint

    par = [{"key": "k", "nominal": 1.0, "value": 1.2, "se": 0.3, "identified": False},
           {"key": "g", "nominal": 2.0, "value": 2.1, "se": 0.01, "identified": True}]
    C = {"joint_calibration": {"recordings": ["a", "b"], "start": "a", "cost_over_noise_floor": 5.1,
                               "stopped_short": True, "parameters": par},
         "calibration_agreement": {"k": {"per_recording": {"a": {"value": 1.25, "se": 0.4}}}}}
    (t,) = _joint(C)
    assert [r[0] for r in t.rows] == ["k", "g"] and [r[3] for r in t.rows] == ["no", "yes"]
    assert t.rows[0][4] == "1.25 +- 0.4" and t.rows[0][5] == "-" and "stopped short" in t.caption
    assert _joint({}) == []

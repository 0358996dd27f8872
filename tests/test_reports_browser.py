"""The reports in a real headless browser (Chromium) and the PDF page by page (pdftoppm): one layout for every
calibration and diagnosis, no clipped title, every axis labelled with its unit, every console caution in the page,
no empty axes, every picture loads, and every PDF page renders.

Chromium and poppler-utils are Debian packages that ``.ci/run`` installs when absent; where they cannot be
installed this module skips with one line.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from rimu.cli import main
from tests.conftest import shared_data

CHROMIUM = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)), None)
PDFTOPPM = shutil.which("pdftoppm")
pytestmark = pytest.mark.skipif(CHROMIUM is None or PDFTOPPM is None,
                                reason="chromium or pdftoppm not installed (apt-get install chromium poppler-utils)")

_CHECK = """<script>
window.addEventListener('load', () => {
  const res = {problems: document.body.dataset.problems || '', svgs: 0, imgs: 0, badimg: [], clipped: [],
               nounit: [], nolabel: 0, titles: [], overflow: document.documentElement.scrollWidth > window.innerWidth + 2,
               text: document.body.innerText};
  document.querySelectorAll('figure svg').forEach(svg => {
    res.svgs++;
    const r = svg.getBoundingClientRect();
    svg.querySelectorAll('text').forEach(t => {
      const b = t.getBoundingClientRect();
      if (b.width && (b.left < r.left - 1 || b.right > r.right + 1 || b.top < r.top - 1 || b.bottom > r.bottom + 1))
        res.clipped.push(t.textContent);
    });
    svg.querySelectorAll('[id^="xlabel-"], [id^="ylabel-"]').forEach(g => {
      if (!/\\[[^\\]]+\\]/.test(g.textContent)) res.nounit.push(g.textContent);
    });
    res.nolabel += svg.querySelectorAll('[id^="ylabel-"]').length ? 0 : 1;
    svg.querySelectorAll('[id^="title-"]').forEach(g => res.titles.push(g.textContent.trim()));
  });
  document.querySelectorAll('img').forEach(i => { res.imgs++; if (!i.complete || i.naturalWidth === 0) res.badimg.push(i.alt); });
  const pre = document.createElement('pre'); pre.id = 'rimu-check'; pre.textContent = JSON.stringify(res);
  document.body.appendChild(pre);
});
</script>"""


def _browse(html: Path, tmp: Path) -> dict:
    page = tmp / (html.stem + "-checked.html")
    page.write_text(html.read_text().replace("</body>", _CHECK + "</body>"))
    r = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--window-size=1200,900",
                        "--virtual-time-budget=10000", "--dump-dom", page.as_uri()],
                       capture_output=True, text=True, timeout=120)
    m = re.search(r'<pre id="rimu-check">(.*?)</pre>', r.stdout, re.S)
    assert m, (r.returncode, r.stderr[-2000:])
    import html as _h

    return json.loads(_h.unescape(m.group(1)))


def _pdf_pages(pdf: Path, tmp: Path) -> int:
    info = subprocess.run(["pdfinfo", str(pdf)], capture_output=True, text=True, timeout=60)
    pages = int(re.search(r"Pages:\s+(\d+)", info.stdout).group(1))
    out = tmp / pdf.stem
    subprocess.run([PDFTOPPM, "-r", "20", "-png", str(pdf), str(out)], check=True, timeout=120)
    rendered = sorted(tmp.glob(pdf.stem + "-*.png"))
    assert len(rendered) == pages and all(p.stat().st_size > 100 for p in rendered), (pages, rendered)
    return pages


def _console(capsys, argv: list) -> list[str]:
    assert main([str(a) for a in argv]) == 0
    return capsys.readouterr().out.splitlines()


def _cautions(lines: list[str]) -> list[str]:
    return [ln.strip() for ln in lines if "caution" in ln or ln.strip().startswith("note:")]


def _assert_page(res: dict, cautions: list[str], min_figures: int) -> None:
    assert res["problems"] == "", res["problems"]
    assert res["svgs"] + res["imgs"] >= min_figures and not res["badimg"], res
    assert not res["clipped"], res["clipped"]
    assert not res["nounit"] and res["nolabel"] == 0, (res["nounit"], res["nolabel"])
    assert not res["overflow"]
    text = " ".join(res["text"].split())
    missing = [c for c in cautions if " ".join(c.split()) not in text]
    assert not missing, missing


def test_calibration_reports_render(tmp_path, capsys):
    from rimu.session import save_session
    from rimu.sim.handheld import handheld_run

    # a turntable session (Cho & Park) and a hand-held one (poses of unknown attitude, motions between them)
    assert main(["simulate", "-o", str(tmp_path / "table.npz"), "--duration", "2"]) == 0
    save_session(handheld_run(n_poses=12, seed=1).session, tmp_path / "hand.npz")
    capsys.readouterr()
    for name, extra in (("table", []), ("hand", ["--method", "handheld"])):
        out = _console(capsys, ["calibrate", tmp_path / f"{name}.npz", *extra, "-o", tmp_path / f"{name}.json",
                                "--report", tmp_path / name])
        res = _browse(tmp_path / name / "calibration.html", tmp_path)
        _assert_page(res, _cautions(out), 1)
        assert "Parameters (1-sigma)" in res["text"]
        if name == "hand":
            assert {"accelerometers: gravity norm per pose", "gyros: rotation misfit per motion"} <= set(res["titles"])
        assert _pdf_pages(tmp_path / name / "calibration.pdf", tmp_path) >= 2


def test_diagnosis_report_renders_with_the_console_cautions(tmp_path, capsys):
    folder = shared_data("imucal_ferraris_session")
    out = _console(capsys, ["diagnose", folder, "--report", tmp_path / "rep"])
    cautions = _cautions(out)
    assert any("cannot be told from errors of the rig's positions" in c for c in cautions)
    res = _browse(tmp_path / "rep" / "report.html", tmp_path)
    _assert_page(res, cautions, 4)
    assert _pdf_pages(tmp_path / "rep" / "report.pdf", tmp_path) >= 3


def test_array_report_renders(tmp_path, capsys):
    from tests.test_figures_units import _array_npz

    npz = _array_npz(tmp_path, "arr.npz", 1.0, 1.0)
    out = _console(capsys, ["array", npz, "--report", tmp_path / "rep"])
    res = _browse(tmp_path / "rep" / "array_report.html", tmp_path)
    _assert_page(res, [ln[len("note: "):] for ln in out if ln.startswith("note: ")], 1)
    assert "gyro: each triad against the array, in motion" in res["titles"]
    assert _pdf_pages(tmp_path / "rep" / "array_report.pdf", tmp_path) >= 2


def test_replay_report_renders(tmp_path, capsys):
    """rimu replay --report: parity, alarms, validity and isolations on one time axis, in the one layout; the
    console's note (the window detector's correlated statistic) is in the page, the isolation in its events."""
    assert main(["simulate", "-o", str(tmp_path / "s.npz"), "--duration", "1"]) == 0
    assert main(["calibrate", str(tmp_path / "s.npz"), "-o", str(tmp_path / "cal.json"), "-q"]) == 0
    capsys.readouterr()
    # with the in-flight self-calibration: its tracked terms are sections of the same page and PDF (issue 27)
    out = _console(capsys, ["replay", tmp_path / "s.npz", "--calibration", tmp_path / "cal.json", "--detector",
                            "glt_window", "--inject", "bias:gyro:y2:5:20sigma", "--selfcal", "--selfcal-bias-rw",
                            "1e-12", "--report", tmp_path / "rep"])
    cautions = _cautions(out)
    assert any("--p-fa is per sample" in c for c in cautions), out
    res = _browse(tmp_path / "rep" / "replay_report.html", tmp_path)
    _assert_page(res, cautions, 1)
    assert {"gyro: parity statistic and alarms", "gyro: validity of the estimate",
            "gyro: sensors in use and isolations", "accel: estimate (master-body frame)"} <= set(res["titles"])
    assert re.search(r"gyro\s+5\.0\d\d\s+\d+\s+isolated\s+y2", res["text"]), res["text"][:3000]
    assert {f"{k}: tracked {b} (without its common mode), 1-sigma band" for k in ("gyro", "accel")
            for b in ("bias", "scale")} <= set(res["titles"]), res["titles"]
    assert "Self-calibration: gyro" in res["text"] and "Self-calibration: accel" in res["text"]
    assert res["svgs"] >= 3
    assert _pdf_pages(tmp_path / "rep" / "replay_report.pdf", tmp_path) >= 4
    for png in ("replay.png", "selfcal-gyro.png", "selfcal-accel.png"):
        assert (tmp_path / "rep" / png).stat().st_size > 1000


def test_selfcal_report_renders(tmp_path, capsys):
    """rimu selfcal --report writes the one layout (issue 27): the console's lines, the terms at the end as a table
    and their history as a figure with a unit on every axis, in one HTML page and a PDF."""
    import numpy as np

    from rimu.calibration import Calibration
    from rimu.session import Segment, Session, save_session
    from rimu.sim.multitriad import triad_array
    from tests.fdi.selfcal_flight import flight

    geo = triad_array(2)
    F = flight(geo, hours=0.05, fs=10.0, seed=3)
    seg = Segment("flight", "motion", F.t, {"gyro": F.Y}, temperature=F.temperature)
    save_session(Session([seg], {"gyro": geo}, 10.0, raw_unit="rad/s"), tmp_path / "f.npz")
    Calibration({"gyro": F.cal}, raw_unit="rad/s").save(tmp_path / "cal.json")
    out = _console(capsys, ["selfcal", tmp_path / "f.npz", "--calibration", tmp_path / "cal.json", "-o",
                            tmp_path / "cal2.json", "--bias-rw", repr(float(np.asarray(F.settings.bias_rw)[0])),
                            "--report", tmp_path / "rep"])
    console = [ln for ln in out if "samples over" in ln or "windows absorbed" in ln]
    assert len(console) == 2, out
    res = _browse(tmp_path / "rep" / "selfcal_report.html", tmp_path)
    _assert_page(res, console + _cautions(out), 1)
    assert {"gyro: tracked bias (without its common mode), 1-sigma band",
            "gyro: tracked scale (without its common mode), 1-sigma band"} <= set(res["titles"]), res["titles"]
    row = next(ln.split()[0] for ln in out if "bias" in ln and "+-" in ln)   # a sensor's row of the console
    assert "Self-calibration: gyro" in res["text"] and row in res["text"]
    assert _pdf_pages(tmp_path / "rep" / "selfcal_report.pdf", tmp_path) >= 2

"""The commissioning report: rendered by a real headless browser (Debian's chromium) with no console
errors, its tables carrying the numbers of --json, printed to PDF; and what it refuses."""

import html
import json
import os
import re
import subprocess
import unicodedata

import pytest

from ambdaq.report.pdf import HEADLESS
from report_page import Tables


pytestmark = pytest.mark.xdist_group("report-session")  # one worker builds the module's files; the other runs other tests


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A commissioning session's files from the simulated spindle (generated unpaced)."""
    from click.testing import CliRunner

    from ambdaq.cli.main import cli
    from ambdaq.documents.coefficients import file_sha256
    from ambdaq.workflows.push import append_local_log

    d = tmp_path_factory.mktemp("session")

    def run(*args):
        r = CliRunner().invoke(cli, [str(a) for a in args])
        assert r.exit_code == 0, r.output

    axes = ("front_x", "front_y", "rear_x", "rear_y", "axial")
    for a in axes:
        run("sim", "generate", "--excite", f"{a}:2", "--duration", "2", "-q", "-o", d / f"gs_{a}.mcap")
    run("iso", "stability", *[d / f"gs_{a}.mcap" for a in axes], "-o", d / "stability.json")
    run("sim", "generate", "--rpm", "slowroll", "--duration", "2", "-q", "-o", d / "slow.mcap")
    run("runout", "identify", d / "slow.mcap", "-o", d / "coef.json")
    run("sim", "generate", "--rpm", "0:30000:3", "--duration", "3", "-q", "-o", d / "runup.mcap")
    run("sim", "generate", "--rpm", "30000", "--duration", "2", "-q", "-o", d / "before.mcap")
    run("sim", "generate", "--rpm", "30000", "--duration", "2", "--ff", "lms", "-q", "-o", d / "after.mcap")
    run("balance", "forces", d / "after.mcap", "--coefficients", d / "coef.json", "--max-rpm", "60000", "--grade",
        "G16", "--record", d / "balance.json")
    os.environ["AMBDAQ_STATE_DIR"] = str(d / "state")
    try:  # the push log as push writes it: one entry of these coefficients, one of another file
        append_local_log({"host_time": "2026-11-23T10:00:00Z", "bank": 1, "crc32": "0x1a2b3c4d", "file": "coef.json",
                          "file_sha256": file_sha256(d / "coef.json"), "target": "serial:///dev/pts/5",
                          "host": "bench", "effective_sample": 123456})
        append_local_log({"host_time": "2026-11-22T09:00:00Z", "bank": 0, "crc32": "0x0", "file": "old.json",
                          "file_sha256": "0" * 64, "target": "serial:///dev/pts/5", "host": "bench",
                          "effective_sample": 1})
    finally:
        del os.environ["AMBDAQ_STATE_DIR"]
    return d


def test_report_renders_in_chromium_with_the_numbers_of_json(session, run_cli, chromium, tmp_path):
    page, pdf = tmp_path / "report.html", tmp_path / "report.pdf"
    r = run_cli("report", "--stability", session / "stability.json", "--runup", session / "runup.mcap",
                "--coefficients", session / "coef.json", "--before", session / "before.mcap", "--after",
                session / "after.mcap", "--push-log", session / "state" / "push.log", "--model", "spindle", "--operating", "1000:20000", "-o", page,
                "--pdf", pdf, "--json", "--balancing", session / "balance.json")
    assert r.exit_code == 0, r.output
    data = json.loads(r.stdout)
    # self-contained: no file or address outside the page
    text = page.read_text()
    assert not re.search(r'(src|href)="(?!data:)', text)

    shot = tmp_path / "report.png"
    browse = [chromium, *HEADLESS, f"--user-data-dir={tmp_path / 'profile'}", "--enable-logging=stderr", "--v=0"]
    done = subprocess.run([*browse, "--window-size=1200,3000", f"--screenshot={shot}", page.as_uri()],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and shot.stat().st_size > 100_000, done.stderr[-2000:]
    console = [line for line in done.stderr.splitlines() if "CONSOLE" in line or "Uncaught" in line
               or "Failed to load resource" in line]
    assert console == [], console
    dom = subprocess.run([*browse, "--dump-dom", page.as_uri()], capture_output=True, text=True, timeout=120)
    assert dom.returncode == 0
    tables = Tables()
    tables.feed(dom.stdout)  # the page as the browser built it

    # every number in the tables is the one --json printed, rounded as its column says: rpm and Hz
    # whole with thousands separators, |Gs| to 0.01, dB to 0.1, coherence to 0.001, um to 0.01
    stab = tables.tables["stability"]
    assert len(stab) == len(data["stability"]["rows"]) == 5
    for cells, row in zip(stab, data["stability"]["rows"]):
        assert cells[:6] == [f"{row['speed_rpm']:,.0f}", row["axis"], f"{row['peak']:.2f}", f"{row['peak_db']:.1f}",
                             f"{row['peak_hz']:,.0f}", f"{row['coherence_at_peak']:.3f}"]
        assert cells[6] == row["zone"]
    vib = tables.tables["vibration"]
    assert len(vib) == len(data["vibration"]["bands"]) == 12  # 2 bearings x 6 bands of 5,000 rpm
    for cells, band in zip(vib, data["vibration"]["bands"]):
        assert cells == [band["bearing"], f"{band['rpm_from']:,.0f}", f"{band['rpm_to']:,.0f}", str(band["windows"]),
                         f"{band['max_um']:.2f}", f"{band['ratio_cmin']:.3f}", band["zone"], f"{band['at_rpm']:,.0f}"]
    assert vib[-1][2] == "30,000"  # not "30000.0"
    runout = tables.tables["runout"]
    for cells, (axis, row) in zip(runout, data["runout"]["axes"].items()):
        expect = [axis] + [f"{h[k]:{'+.1f' if k == 'change_db' else '.2f'}}" for h in row["harmonics"]
                           for k in ("before_um", "after_um", "change_db")]
        assert cells == expect + [f"{row['rms_before_um']:.2f}", f"{row['rms_after_um']:.2f}"]
        assert row["harmonics"][0]["change_db"] < -20  # the LMS took the runout out of the command error
    # the run-up's critical speeds against the spindle model (API 684): speeds whole, factors to 0.01;
    # the page says which gains the model's loop holds (the recording's own)
    assert data["runup"]["model_basis"].startswith("the PID gains the recording's controller ran (pid.p 1.6")
    assert html.escape(data["runup"]["model_basis"], quote=False) in dom.stdout
    crit = data["runup"]["critical_speeds"]
    # one code path per number: the run-up's 1X peaks and critical speeds are what runup --json gives
    alone = json.loads(run_cli("runup", session / "runup.mcap", "--coefficients", session / "coef.json", "--model",
                               "spindle", "--operating", "1000:20000", "--orders", "1,2", "--json").stdout)
    assert data["runup"]["peaks_1x"] == alone["peaks_1x"] and crit == alone["critical_speeds"]
    assert len(crit) >= 1 and tables.tables["critical-speeds"] == [
        [f"{c['predicted_rpm']:,.0f}", f"{c['predicted_amplification']:.2f}", c["whirl"] or "–",
         "–" if c["measured_rpm"] is None else f"{c['measured_rpm']:,.0f}", c["axis"] or "–",
         "–" if c["measured_amplification"] is None else f"{c['measured_amplification']:.2f}",
         f"{c['margin']:.1%} / {c['margin_required']:.1%}", "pass" if c["passed"] else "FAIL", c["rule"]] for c in crit]
    # the runout pushed, with the uncertainty runout identify stated for each harmonic (its scatter
    # against that bound: tests/test_runout.py): what runout identify --json printed, one code path
    c = data["coefficients"]
    identified = json.loads(run_cli("runout", "identify", session / "slow.mcap", "-o", tmp_path / "again.json",
                                    "--json").stdout)
    assert c["axes"] == identified
    assert tables.tables["coefficients"] == [
        [axis] + [f"{h[key]:{fmt}}" for h in hs[:2]
                  for key, fmt in (("amplitude_um", ".2f"), ("phase_deg", ".1f"), ("u_um", ".3f"))]
        for axis, hs in c["axes"].items()]
    slow = json.loads((session / "coef.json").read_text())["source"]["uncertainty_m"]
    for axis, hs in c["axes"].items():
        assert [h["u_um"] for h in hs] == [round(u * 1e6, 5) for u in slow[axis]]
        assert all(0 < h["u_um"] < 0.1 * h["amplitude_um"] for h in hs[:2])  # 800 rpm slow roll, 2 s: well measured
    # APHT of the run after the push: the LMS adapting from zero, its command error's 1X falling; the
    # first and the last window of what apht --json prints
    a = data["apht"]
    assert a["windows"] == 4 and a["window_s"] == 0.5 and a["rpm"] == pytest.approx(30000, abs=1)
    alone = json.loads(run_cli("apht", session / "after.mcap", "--coefficients", session / "coef.json",
                               "--json").stdout)
    for j, row in enumerate(a["rows"]):
        for key, series in (("gap", alone["gap_um"]), ("error", alone["error_um"])):
            for name, w in (("first", 0), ("last", -1)):
                assert row[f"{key}_{name}"] == {"amplitude": series["amplitude"][w][0][j],
                                                "phase_deg": series["phase_deg"][w][0][j]}, (row["axis"], key, name)
    assert tables.tables["apht"] == [[row["axis"], *(f"{row[k]['amplitude']:.2f}" if u == "um" else f"{row[k]['phase_deg']:.1f}"
                                                     for k in ("gap_first", "gap_last", "error_first", "error_last")
                                                     for u in ("um", "deg"))] for row in a["rows"]]
    for row in a["rows"]:
        assert row["error_last"]["amplitude"] < 0.2 * row["error_first"]["amplitude"], row
    # the balancing record: what balance forces --json printed for the run after, its unbalance and
    # correction masses in the tables (g mm to 0.001, degrees to 0.1, grams to 0.0001)
    b = data["balancing"]
    alone = json.loads(run_cli("balance", "forces", session / "after.mcap", "--coefficients", session / "coef.json",
                               "--max-rpm", 60000, "--grade", "G16", "--json").stdout)
    assert b["unbalance"] == alone["unbalance_estimated"] and b["correction"] == alone["correction"]
    assert (b["grade"], b["grade_mm_s"], b["grade_std_mm_s"]) == (alone["grade"], alone["grade_mm_s"], alone["grade_std_mm_s"])
    assert tables.tables["balancing-unbalance"] == [[p, f"{u['g_mm']:.3f}", f"{u['std_g_mm']:.3f}", f"{u['deg']:.1f}"]
                                                    for p, u in b["unbalance"].items()]
    assert tables.tables["balancing-correction"] == [[m["plane"], f"{m['grams']:.4f}", f"{m['deg']:.1f}",
                                                      f"{m['radius_mm']:g}"] for m in b["correction"]]
    # the grade now and the grade predicted after the correction (ISO 21940-11/-14), as --json states them
    p = alone["predicted_after"]
    assert b["predicted_after"] == {k: p[k] for k in ("grade_mm_s", "at_most_mm_s", "level", "grade",
                                                      "mass_tolerance_g", "angle_tolerance_deg")}
    assert tables.tables["balancing-grade"] == [
        ["now (this record's run)", f"{b['grade_mm_s']:.3g}", f"{b['grade_std_mm_s']:.3g}", "–", b["grade"]],
        ["predicted after the correction", f"{p['grade_mm_s']:.3g}", "–", f"{p['at_most_mm_s']:.3g}", p["grade"]]]
    (entry,) = data["push_log"]  # only the push of these coefficients
    assert tables.tables["push-log"] == [["2026-11-23 10:00:00 UTC", "1", "0x1a2b3c4d", "coef.json",
                                          entry["file_sha256"][:16], "serial:///dev/pts/5", "123456"]]
    # the machine: every device of every input (run-up, before, after, the five stability runs), each once
    devices = data["machine"]["devices"]
    assert [d["device"] for d in devices] == ["rig"] and devices[0]["url"].startswith("sim://spindle")
    assert set(devices[0]["recordings"]) == {"runup.mcap", "before.mcap", "after.mcap",
                                             *(f"gs_{a}.mcap" for a in ("front_x", "front_y", "rear_x", "rear_y", "axial"))}
    assert len(data["machine"]["recordings"]) == 8 and tables.tables["machine"][0][0] == "rig"
    # the verdict first: each standard's worst zone, the runout on its worst axis, the open items
    verdict = data["verdict"]
    worst_gs = max(data["stability"]["rows"], key=lambda r: (r["zone"], r["peak"]))
    worst_band = max(data["vibration"]["bands"], key=lambda b: b["ratio_cmin"])
    assert [(line["standard"], line["zone"]) for line in verdict["lines"]] == [
        ("ISO 14839-3", worst_gs["zone"]), ("ISO 14839-2", worst_band["zone"]), ("API 684", None),
        ("Ro et al. runout feedforward", None), ("ISO 21940-11", None), ("ISO 21940-14", None)]
    assert verdict["lines"][4]["result"].startswith(f"{b['grade']} ({b['grade_mm_s']:.3g} ± ")
    assert verdict["lines"][4]["result"].endswith(f"; predicted after it at most {p['at_most_mm_s']:.3g} mm/s ({p['grade']})")
    # the job asked for G16 (--grade): ISO 21940-14's acceptance, as balance forces --json states it
    assert b["acceptance"] == alone["acceptance"] and verdict["lines"][5]["check"] == "rotor balance against G16"
    assert verdict["lines"][5]["result"].startswith("accepted after balancing" if alone["acceptance"]["after_balancing"]
                                                    else "not accepted")
    assert verdict["lines"][2]["result"] == f"{sum(c['passed'] for c in crit)} of {len(crit)} verified against the spindle model"
    assert tables.tables["verdict"][0][2].startswith(f"zone {worst_gs['zone']} (") and worst_gs["axis"] in \
        tables.tables["verdict"][0][2]
    assert dom.stdout.index('id="verdict"') < dom.stdout.index('id="machine"') < dom.stdout.index('id="stability"')
    assert pdf.read_bytes()[:5] == b"%PDF-" and pdf.stat().st_size > 100_000
    # in the PDF, every section heading is on the page of what it introduces: its table's first
    # column heading (or, without a table, its first paragraph), never alone at a page's foot
    from pypdf import PdfReader

    pages = [[unicodedata.normalize("NFKC", line).strip() for line in p.extract_text().splitlines() if line.strip()]
             for p in PdfReader(pdf).pages]  # NFKC: the PDF's ligatures (ﬁ, ﬃ) as letters
    assert len(pages) >= 3
    sections = re.findall(r"<h2>(.*?)</h2>(.*?)(?=<h2>|</body>)", dom.stdout, re.S)
    assert len(sections) == 10
    for heading, body in sections:
        table = re.search(r"<tr>(.*?)</tr>", body, re.S)  # the first table's header row, else the first paragraph
        first = table.group(1) if table else re.search(r"<p[^>]*>(.*?)</p>", body, re.S).group(1)
        words = unicodedata.normalize("NFKC", html.unescape(re.sub(r"<[^>]+>", " ", first))).split()
        heading = html.unescape(heading)
        (page,) = [lines for lines in pages if heading in lines]
        after = iter(" ".join(page[page.index(heading) + 1:]).split())  # a cell's words may wrap onto lines
        assert all(word in after for word in words), (heading, words, page[-3:])  # every word, in order


def test_what_a_report_refuses_is_one_line_exit_2(session, run_cli, tmp_path):
    r = run_cli("report", "-o", tmp_path / "r.html")
    assert r.exit_code == 2 and "needs at least one of --stability, --runup, --before/--after or --drops" in r.output
    r = run_cli("report", "--before", session / "before.mcap", "-o", tmp_path / "r.html")
    assert r.exit_code == 2 and "--before and --after go together" in r.output
    r = run_cli("report", "--runup", session / "runup.mcap", "--operating", "1000:20000", "-o", tmp_path / "r.html")
    assert r.exit_code == 2 and "--operating checks the critical speeds of a --model" in r.output
    r = run_cli("report", "--runup", session / "runup.mcap", "--model", "spindle", "--operating", "20000:1000",
                "-o", tmp_path / "r.html")
    assert r.exit_code == 2 and "expected FROM:TO in rpm, FROM below TO" in r.output
    bad = tmp_path / "stability.json"
    bad.write_text((session / "stability.json").read_text().replace('"zone": "A"', '"zone": "B"', 1))
    r = run_cli("report", "--stability", bad, "-o", tmp_path / "r.html")
    assert r.exit_code == 2 and "checksum mismatch" in r.output
    r = run_cli("report", "--stability", session / "stability.json", "--push-log", tmp_path / "none.log",
                "-o", tmp_path / "r.html")
    assert r.exit_code == 2 and "no such push log" in r.output
    r = run_cli("report", "--stability", session / "stability.json", "--balancing", session / "coef.json",
                "-o", tmp_path / "r.html")
    assert r.exit_code == 2 and "not an ambdaq balancing record" in r.output, r.output
    assert not (tmp_path / "r.html").exists()


@pytest.mark.realtime
def test_the_machine_table_tells_devices_apart_by_identity_not_by_url(run_cli, tmp_path):
    """Two recordings of the simulated spindle in one process reach its CAN devices over another
    virtual bus each time (ambdaq-sim-N): each device is listed once, by its model and serial, with
    both URLs and both recordings (the README's commands had listed the same four devices ten times)."""
    from ambdaq.daq import open_recording
    from ambdaq.workflows.commissioning import machine_identity

    files = [tmp_path / "a.mcap", tmp_path / "b.mcap"]
    for f in files:
        assert run_cli("record", "--device", "sim://spindle", "--duration", "0.3", "-q", "-o", f).exit_code == 0
    devices = machine_identity([open_recording(f) for f in files])["devices"]
    assert sorted(d["device"] for d in devices) == ["rig", "rig-accelerometer", "rig-amplifier", "rig-gap_sensor",
                                                    "rig-keyphasor"]
    for d in devices:
        assert d["recordings"] == ["a.mcap", "b.mcap"] and d["serial"], d
    can = [d for d in devices if d["device"] != "rig"]
    assert all(len(d["urls"]) == 2 and d["urls"][0] != d["urls"][1] for d in can), can

"""The commissioning report's page: one self-contained HTML file from a
:class:`~ambdaq.workflows.commissioning.Commissioning` (docs/iso.md).

The page carries its figures inline (PNG, base64) and its style: it opens from a mail attachment
or a USB stick with no network, and prints.  It opens with the verdict (each standard's worst zone,
the runout before and after, the open items). Every number in its tables is the value ``--json``
prints (the result's ``data``: one code path per number), rounded as its column says
(:data:`FORMATS`) and written with its unit in the header.
"""

from __future__ import annotations

import base64
import html
import io
import json
from pathlib import Path

import numpy as np

from ..analysis.iso14839 import ZoneLimits

STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }
h1 { font-size: 1.6em; } h2 { font-size: 1.25em; border-bottom: 1px solid #ccc; margin-top: 2em; }
table { border-collapse: collapse; margin: 0.8em 0; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 0.25em 0.6em; text-align: right; }
th { background: #eee; } td.text, th.text { text-align: left; }
td.zone-A { background: #d8f0d8; } td.zone-B { background: #f3f0c8; } td.zone-C { background: #f6dcc0; }
td.zone-D { background: #f4c4c4; } td.zone-none { background: #ddd; }
figure { margin: 1em 0; } figure img { max-width: 100%; } figcaption { font-size: 0.85em; color: #555; }
p.note { font-size: 0.9em; color: #444; }
#verdict-box { border: 2px solid #555; padding: 0 1em 0.5em; margin: 1em 0 2em; }
#verdict-box h2 { margin-top: 0.6em; border: none; } #verdict-box td { text-align: left; }
/* a heading and its introduction keep with the table or figure they introduce; rows and figures whole */
@media print { body { margin: 0; } h2, p.note { break-after: avoid; } div.keep, figure, tr { break-inside: avoid; } }
"""

FORMATS = {  # a column's number as the report writes it: the --json value rounded for reading
    "rpm": "{:,.0f}", "gain": "{:.2f}", "db": "{:.1f}", "hz": "{:,.0f}", "coherence": "{:.3f}", "um": "{:.2f}",
    "ratio": "{:.3f}", "count": "{:d}", "change_db": "{:+.1f}", "factor": "{:.2f}", "s": "{:.3f}", "m_s": "{:.3f}",
    "j": "{:.3g}", "deg": "{:.1f}", "u": "{:.3f}", "g": "{:.4f}", "g_mm": "{:.3f}", "mm": "{:g}",
    "mm_s": "{:.3g}",
}


def number(value, kind: str) -> str:
    """``value`` as the report writes a number of ``kind`` (FORMATS), or "–" for none."""
    return "–" if value is None else FORMATS[kind].format(value)


def when(stamp: str) -> str:
    """An ISO 8601 time as the report writes it: to the second, in UTC ("2026-11-23 10:00:00 UTC")."""
    from datetime import datetime, timezone

    try:
        t = datetime.fromisoformat(stamp.replace("Z", "+00:00"))
    except (ValueError, AttributeError):
        return stamp or "–"
    return t.astimezone(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC") if t.tzinfo else t.strftime("%Y-%m-%d %H:%M:%S")


def _cell(value, cls: str = "", kind: str | None = None) -> str:
    text = number(value, kind) if kind else "–" if value is None else (value if isinstance(value, str) else json.dumps(value))
    return f'<td class="{cls}">{html.escape(text)}</td>' if cls else f"<td>{html.escape(text)}</td>"


def _table(headers: list[str], rows: list[list[str]], table_id: str) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in headers)
    body = "".join(f"<tr>{''.join(r)}</tr>" for r in rows)
    return f'<table id="{table_id}"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>'


def _figure(png: bytes, caption: str) -> str:
    data = base64.b64encode(png).decode()
    return (f'<figure><img alt="{html.escape(caption)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def _png(fig) -> bytes:
    """A figure as PNG bytes (closed)."""
    from ..figures import save

    buf = io.BytesIO()
    save(fig, buf)
    return buf.getvalue()


def render(found, title: str) -> str:
    """The report page of a :class:`~ambdaq.workflows.commissioning.Commissioning`."""
    from ..figures.apht import draw_apht
    from ..figures.iso import draw_stability, draw_vibration
    from ..figures.runup import draw_runup

    d = found.data
    parts = [f"<h1>{html.escape(title)}</h1>"]
    verdict = d["verdict"]
    rows = [[_cell(line["check"], "text"), _cell(line["standard"], "text"),
             _cell(line["result"], f"zone-{line['zone']} text" if line["zone"] else "text")] for line in verdict["lines"]]
    parts += ['<section id="verdict-box"><h2>Verdict</h2>', _table(["check", "rule", "result"], rows, "verdict")]
    if verdict["open_items"]:
        parts.append('<p class="note">Open items:</p><ul id="open-items">'
                     + "".join(f"<li>{html.escape(item)}</li>" for item in verdict["open_items"]) + "</ul>")
    else:
        parts.append('<p class="note" id="open-items">No open items.</p>')
    parts.append("</section>")
    m = d["machine"]
    if m:
        rows = [[_cell(dev["device"], "text"), *[_cell(dev.get(k), "text") for k in ("kind", "model", "serial", "firmware")],
                 _cell(", ".join(dev.get("urls") or [dev.get("url") or "–"]), "text"),
                 _cell(", ".join(dev["recordings"]), "text")] for dev in m["devices"]]
        made = "; ".join(f"{Path(r['recording']).name} {when(r['start_time'])} on {r['host'] or '–'} (ambdaq "
                         f"{r['ambdaq_version'] or '–'})" for r in m["recordings"])
        parts += ["<h2>Machine</h2>", f'<p class="note">Every device of every recording of the session: {html.escape(made)}.</p>',
                  _table(["device", "kind", "model", "serial", "firmware", "URL", "in"], rows, "machine")]
    s = d["stability"]
    if s:
        limits = ZoneLimits(*s["limits_peak_gs"])
        rows = [[_cell(r["speed_rpm"], kind="rpm"), _cell(r["axis"], "text"), _cell(r["peak"], kind="gain"),
                 _cell(r["peak_db"], kind="db"), _cell(r["peak_hz"], kind="hz"), _cell(r["coherence_at_peak"], kind="coherence"),
                 _cell(r["zone"] or f"not measured: {r['reason']}", f"zone-{r['zone'] or 'none'} text")]
                for r in s["rows"]]
        curves = [{"speed_rpm": r.speed_rpm, "axis": r.axis, "freq_hz": np.array(r.curves.freq_hz),
                   "gs": np.array([np.nan if v is None else v for v in r.curves.gs_real])
                   + 1j * np.array([np.nan if v is None else v for v in r.curves.gs_imag]),
                   "coherence": np.array(r.curves.coherence), "peak_db": r.peak_db, "zone": r.zone}
                  for r in found.stability.runs]
        parts += ["<h2>Stability margin, ISO 14839-3</h2>",
                  f'<p class="note">Peak of the sensitivity function |Gs| per axis and speed, measured with the '
                  f"controller's test signal at the sensor summing point ({html.escape(s['file'])}). Zone limits "
                  f"A/B {limits.ab:g}, B/C {limits.bc:g}, C/D {limits.cd:g} (peak |Gs|); a grade needs a coherence "
                  f"of at least {s['min_coherence']:g} at the peak.</p>",
                  _table(["speed [rpm]", "axis", "peak |Gs|", "peak [dB]", "at [Hz]", "coherence", "zone"], rows, "stability"),
                  _figure(_png(draw_stability(curves, limits)),
                          "Sensitivity function |Gs| in dB against frequency in Hz, per axis; dashed: the zone limits.")]
    c = d.get("controller")
    if c:
        from ..figures.controller import draw_design

        pred = c["prediction"]
        rows = [[_cell(bearing, "text"), _cell("; ".join(labels) or "none", "text")] for bearing, labels in c["sections"].items()]
        pid = [[_cell(a, "text"), _cell(c["pid"]["p"][i], kind="factor"), _cell(c["pid"]["i"][i], kind="factor"),
                _cell(c["pid"]["d"][i] * 1e3, kind="factor")] for i, a in enumerate(pred["axes"])]
        axes = [[_cell(r["axis"], "text"), _cell(r["peak_db"], kind="db"), _cell(r["at_hz"], kind="hz"),
                 _cell(r["at_rpm"], kind="rpm"), _cell(r["zone"] or "unstable", f"zone-{r['zone'] or 'none'} text"),
                 _cell(r["identified_standstill_db"], kind="db")] for r in c["axes"]]
        compared = [[_cell(x["speed_rpm"], kind="rpm"), _cell(x["axis"], "text"), _cell(x["measured_db"], kind="db"),
                     _cell(x["predicted_db"], kind="db"), _cell(x["difference_db"], kind="change_db"),
                     _cell("as predicted" if x["within"] else "NOT as predicted", "text")] for x in c["compared"]]
        nan = (lambda rows_: np.array([[np.nan if v is None else v for v in r] for r in rows_], dtype=float))
        rb, pt = c["robustness"], c["perturbed"]
        parts += ["<h2>Controller</h2>",
                  f'<p class="note">The controller design pushed ({html.escape(c["file"])}, from the identified plant '
                  f"{html.escape(str(c['source'].get('plant_model', '–')))}): predicted on the machine's rotor model over "
                  f"speed (docs/tuning.md); {rb['stable']} of {rb['draws']} plants drawn within the identified "
                  f"uncertainty and {pt['stable']} of {pt['plants']} perturbed plants stable with it.</p>",
                  _table(["bearing", "sections"], rows, "controller-sections"),
                  _table(["axis", "P [V/V]", "I [1/s]", "D [ms]"], pid, "controller-pid"),
                  _table(["axis", "predicted worst peak [dB]", "at [Hz]", "at [rpm]", "zone", "identified at standstill [dB]"],
                         axes, "controller-prediction"),
                  _table(["speed [rpm]", "axis", "measured [dB]", "predicted [dB]", "difference [dB]",
                          f"within {c['tolerance_db']:g} dB"], compared, "controller-compared"),
                  _figure(_png(draw_design(np.array(pred["speeds_rpm"]), nan(pred["peak_db"]), nan(pred["stock_peak_db"]),
                                           pred["axes"], c["sections"])),
                          "Predicted peak |Gs| in dB against speed in rpm per axis: the design (solid) and the stock "
                          "controller (dashed), its unstable speeds shaded; dotted: the zone limits.")]
    b = d.get("balancing")
    if b:
        unbalance = [[_cell(p, "text"), _cell(u["g_mm"], kind="g_mm"), _cell(u["std_g_mm"], kind="g_mm"),
                      _cell(u["deg"], kind="deg")] for p, u in b["unbalance"].items()]
        masses = [[_cell(m["plane"], "text"), _cell(m["grams"], kind="g"), _cell(m["deg"], kind="deg"),
                   _cell(m["radius_mm"], kind="mm")] for m in b["correction"]]
        runs = ", ".join(f"{r.get('file')} ({r.get('role')})" for r in b["runs"])
        parts += ["<h2>Balancing</h2>",
                  f'<p class="note">From the balancing record {html.escape(b["file"])}: {html.escape(b["method"])} at '
                  f"{number(b['rpm'], 'rpm')} rpm, from {html.escape(runs)}; angles from the key-phasor's mark in the "
                  "direction of rotation (docs/balancing.md).</p>",
                  _table(["plane", "unbalance [g mm]", "± 1σ [g mm]", "at [deg]"], unbalance, "balancing-unbalance"),
                  _table(["plane", "correction [g]", "at [deg]", "radius [mm]"], masses, "balancing-correction")]
        p = b["predicted_after"]
        if b["grade_mm_s"] is not None and p is not None:
            rows = [[_cell("now (this record's run)", "text"), _cell(b["grade_mm_s"], kind="mm_s"),
                     _cell(b["grade_std_mm_s"], kind="mm_s"), _cell("–"), _cell(b["grade"], "text")],
                    [_cell("predicted after the correction", "text"), _cell(p["grade_mm_s"], kind="mm_s"), _cell("–"),
                     _cell(p["at_most_mm_s"], kind="mm_s"), _cell(p["grade"], "text")]]
            parts += [f'<p class="note">ISO 21940-11 grade at {number(b["max_rpm"], "rpm")} rpm; after the correction '
                      f"the median and the bound it stays within with {p['level'] * 100:.0f} % (the estimate's deviation "
                      f"and the masses within {p['mass_tolerance_g']:g} g and {p['angle_tolerance_deg']:g}°, ISO "
                      "21940-14).</p>",
                      _table(["", "grade [mm/s]", "± 1σ [mm/s]", "at most [mm/s]", "class"], rows, "balancing-grade")]
    v = d["vibration"]
    if v:
        limits = ZoneLimits(*v["limits_ratio_cmin"])
        rows = [[_cell(b["bearing"], "text"), _cell(b["rpm_from"], kind="rpm"), _cell(b["rpm_to"], kind="rpm"),
                 _cell(b["windows"], kind="count"), _cell(b["max_um"], kind="um"), _cell(b["ratio_cmin"], kind="ratio"),
                 _cell(b["zone"], f"zone-{b['zone']} text"), _cell(b["at_rpm"], kind="rpm")]
                for b in v["bands"]]
        removed = ("the sensor runout taken out (" + html.escape(v["runout_removed"]["path"]) + "). "
                   + html.escape(v["runout_removed"]["means"][0].upper() + v["runout_removed"]["means"][1:])
                   if v["runout_removed"] else "the sensor runout not taken out")
        parts += ["<h2>Vibration, ISO 14839-2</h2>",
                  f'<p class="note">Largest orbit excursion from its centre per 0.1 s window, worst window per '
                  f"{v['band_rpm']:g} rpm band, against Cmin {v['cmin_um']:g} µm ({html.escape(v['cmin_from'])}), "
                  f"{removed}.</p>",
                  _table(["bearing", "from [rpm]", "to [rpm]", "windows", "max [µm]", "/ Cmin", "zone", "at [rpm]"], rows,
                         "vibration"),
                  _figure(_png(draw_vibration(v["bands"], limits, v["cmin_um"])),
                          "Orbit maximum in µm per speed band in rpm, per bearing; dashed: the zone limits.")]
    r = d["runout"]
    if r:
        rows = []
        for axis, row in r["axes"].items():
            cells = [_cell(axis, "text")]
            for h in row["harmonics"]:
                cells += [_cell(h["before_um"], kind="um"), _cell(h["after_um"], kind="um"),
                          _cell(h["change_db"], kind="change_db")]
            rows.append(cells + [_cell(row["rms_before_um"], kind="um"), _cell(row["rms_after_um"], kind="um")])
        orders = [h["harmonic"] for h in next(iter(r["axes"].values()))["harmonics"]]
        headers = ["axis"] + [f"{k}X {w}" for k in orders for w in ("before [µm]", "after [µm]", "change [dB]")]
        parts += ["<h2>Runout before and after the push</h2>",
                  f'<p class="note">Command error at {r["before"]["rpm"]:,.0f} rpm ({html.escape(r["before"]["path"])}) '
                  f'and {r["after"]["rpm"]:,.0f} rpm ({html.escape(r["after"]["path"])}).</p>',
                  _table(headers + ["RMS before [µm]", "RMS after [µm]"], rows, "runout")]
    c = d.get("coefficients")
    if c is not None:
        shown = [1, 2]  # the largest: Ro et al.'s runout is 1X and 2X dominant
        def harmonic(hs: list[dict], k: int) -> list[str]:
            h = next((h for h in hs if h["harmonic"] == k), {"amplitude_um": None, "phase_deg": None, "u_um": None})
            return [_cell(h["amplitude_um"], kind="um"), _cell(h["phase_deg"], kind="deg"), _cell(h["u_um"], kind="u")]

        rows = [[_cell(axis, "text")] + [cell for k in shown for cell in harmonic(hs, k)] for axis, hs in c["axes"].items()]
        parts += ["<h2>Runout pushed</h2>",
                  f'<p class="note">The sensor runout in {html.escape(Path(c["file"]).name)} ({html.escape(c["method"])}'
                  "), 1X and 2X per axis, each with the standard uncertainty <code>runout identify</code> stated "
                  "for it (the Cramér-Rao bound from the noise it measured; – where the file does not say).</p>",
                  _table(["axis", "1X [µm]", "[°]", "u [µm]", "2X [µm]", "[°]", "u [µm]"], rows, "coefficients")]
    a = d.get("apht")
    if a is not None:
        def vec(v) -> list[str]:
            return [_cell(v["amplitude"], kind="um"), _cell(v["phase_deg"], kind="deg")]

        rows = [[_cell(row["axis"], "text"), *vec(row["gap_first"]), *vec(row["gap_last"]),
                 *(vec(row["error_first"]) + vec(row["error_last"]) if "error_first" in row else [_cell(None, kind="um")] * 4)]
                for row in a["rows"]]
        parts += ["<h2>APHT after the push</h2>",
                  f'<p class="note">1X amplitude and phase against time at {a["rpm"]:,.0f} rpm '
                  f'({html.escape(Path(a["recording"]).name)}, {a["windows"]} windows of {a["window_s"]} s; gap '
                  f'compensation: {html.escape(a["compensation"])}): the first window and the last. An LMS '
                  "converging shows as a command error whose 1X falls; a thermal bow as a gap 1X that turns and "
                  "grows.</p>",
                  _table(["axis", "gap 1X first [µm]", "[°]", "gap 1X last [µm]", "[°]", "error 1X first [µm]", "[°]",
                          "error 1X last [µm]", "[°]"], rows, "apht"),
                  _figure(_png(draw_apht(found.apht)), "APHT: 1X amplitude and phase of the gap, the command error "
                          "and the feedforward per axis against time.")]
    log = d["push_log"]
    if d.get("touchdowns") is not None:
        rows = [[_cell(Path(r["file"]).name, "text")] + ([_cell("no drop in it", "text")] + [_cell(None, kind="rpm")] * 9
                if (t := r["drop"]) is None else [
                    _cell(when(t["contact"]), "text"), _cell(t["speed_rpm"], kind="rpm"),
                    _cell(("≥ " if t["began_before"] else "") + number(t["on_bearing_s"], "s"), "text"),
                    _cell("yes" if t["relevitated"] else "no", "text"), _cell(t["peak_ratio"], kind="ratio"),
                    _cell(t["peak_at"], "text"), _cell(t["whirl"], "text"), _cell(t["amplifier_at_limit"], kind="factor"),
                    _cell(t["impact_speed_m_s"], kind="m_s"), _cell(t["energy_j"], kind="j")])
                for r in d["touchdowns"]]
        parts += ["<h2>Rotor drops, ISO 14839-5</h2>",
                  '<p class="note">Each snapshot file\'s drop onto the touchdown bearings: the speed at the first '
                  "contact, the time on the bearing (≥: the file began with the rotor already down), whether it "
                  "levitated again, the peak excursion over Cmin and where, the whirl while in contact, the "
                  "amplifier's largest output over its limit, and the impact's speed and energy.</p>",
                  _table(["file", "first contact", "rpm", "on bearing s", "levitated again", "peak / Cmin", "at",
                          "whirl", "amplifier / limit", "impact m/s", "energy J"], rows, "touchdowns")]
    parts.append("<h2>Push log</h2>")
    if log:
        rows = [[_cell(when(e["host_time"]), "text"), _cell(e["bank"]), _cell(e["crc32"], "text"), _cell(e["file"], "text"),
                 _cell((e["file_sha256"] or "")[:16], "text"), _cell(e["target"], "text"), _cell(e["effective_sample"])]
                for e in log]
        parts.append(_table(["host time", "bank", "CRC-32", "file", "sha256", "target", "from sample"], rows, "push-log"))
    else:
        parts.append('<p class="note">No push of these coefficients in the push log.</p>')
    if found.runup is not None:
        u = d["runup"]
        peaks = "; ".join(f"{a}: " + (", ".join(f"{p['amplitude_um']} µm at {p['rpm']:,.0f} rpm (amplification "
                                               f"{p['amplification']}{', critical' if p['critical'] else ''})" for p in ps)
                                      or "no 1X peak inside the run")
                          for a, ps in u["peaks_1x"].items())
        parts += ["<h2>Run-up</h2>",
                  f'<p class="note">{u["rpm_from"]:,.0f} to {u["rpm_to"]:,.0f} rpm, {u["windows"]} windows; compensation: '
                  f"{html.escape(u['compensation'])}. 1X peaks: {html.escape(peaks)}."
                  + (f" {html.escape(u['runout_removed'][0].upper() + u['runout_removed'][1:])}." if u["runout_removed"]
                     else "") + "</p>"]
        if u["model"]:
            rows = [[_cell(c["predicted_rpm"], kind="rpm"), _cell(c["predicted_amplification"], kind="factor"),
                     _cell(c["whirl"] or "–", "text"), _cell(c["measured_rpm"], kind="rpm"), _cell(c["axis"] or "–", "text"),
                     _cell(c["measured_amplification"], kind="factor"),
                     _cell("–" if c["margin"] is None else f"{c['margin']:.1%} / {c['margin_required']:.1%}", "text"),
                     _cell("pass" if c["passed"] else "FAIL", "text"),
                     _cell(c["rule"], "text")] for c in u["critical_speeds"]]
            parts.append(f'<p class="note">Critical speeds of the {html.escape(u["model"])} model (forward modes on '
                         f"the 1X line; its loop at {html.escape(u['model_basis'])}) against the run's 1X peaks, by "
                         "API 684's practice.</p>"
                         + (_table(["predicted rpm", "predicted AF", "whirl", "measured rpm", "axis", "measured AF",
                                    "margin / required", "verdict", "rule"], rows, "critical-speeds")
                            if rows else '<p class="note">No critical speed predicted inside the run.</p>'))
        parts += [
                  _figure(_png(draw_runup(found.runup, Path(d["files"]["runup"]).name)),
                          "Order tracking (1X, 2X amplitude in µm and 1X phase in degrees against speed in rpm), the "
                          "1X vector, and the waterfall of the gap spectrum with the order lines.")]
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>'
            f"<style>{STYLE}</style></head><body>{''.join(_kept_together(parts))}</body></html>\n")


def _kept_together(parts: list[str]) -> list[str]:
    """Each section heading, its notes and what they introduce (up to its first table, or the one
    block after the notes) in one ``div.keep``, which a printed page does not break."""
    out: list[str] = []
    i = 0
    while i < len(parts):
        if not parts[i].startswith("<h2>"):
            out.append(parts[i])
            i += 1
            continue
        j = i + 1
        while j < len(parts) and parts[j].startswith('<p class="note"') and "<table" not in parts[j]:
            j += 1
        j = min(j + 1, len(parts))
        out.append('<div class="keep">' + "".join(parts[i:j]) + "</div>")
        i = j
    return out

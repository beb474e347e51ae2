"""The commissioning record of one machine from the files of a session: its identity, the ISO 14839-3
stability table, the ISO 14839-2 zones through a run-up, the runout before and after the push with
the push log, and the run-up's order tracking.  The numbers here are what ``ambdaq report`` puts in
its tables and prints with ``--json``; the figures are drawn from the same objects.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from ..analysis.orders import CriticalLimits
from ..documents.coefficients import Coefficients, file_sha256
from ..daq.recording import Recording, open_recording
from ..acquisition.touchdowns import recorded_drop
from ..errors import BadInputError
from . import iso_stability, iso_vibration, runup_diagnostics
from .apht import Apht, apht
from .balancing import load_record
from .push import push_log_entries
from .runout import RUNOUT_REMOVED, check_recordings, held_unbalance, runout_table, with_rotor

IDENTITY_KEYS = ("kind", "model", "serial", "firmware", "software_version", "url", "sample_rate_hz")


@dataclass
class SessionFiles:
    """What a commissioning session left behind (each optional, at least one given).

    Attributes
    ----------
    stability : Path or None
        ``ambdaq iso stability -o`` results.
    runup : Recording or None
        A run-up or coast-down recording (ISO 14839-2 zones, order tracking).
    coefficients : Path or None
        The runout coefficient file that was pushed (its runout is taken out of the run-up).
    before, after : Recording or None
        Recordings at one speed before and after the push.
    push_log : Path or None
        The host's push log (JSON lines); default: this machine's, if it exists.
    cmin_m : float or None
        Minimum clearance, in m; default: what the run-up's controller reports.
    model : str or None
        The rotordynamic model whose critical speeds the run-up verifies (``spindle``, ``cone``:
        :func:`~ambdaq.workflows.runup_diagnostics.model_modes`); None: not verified.
    drops : list of Recording
        Snapshot files a touchdown trigger caught (``record --snapshot``): the rotor drop each holds
        (ISO 14839-5, :mod:`ambdaq.acquisition.touchdowns`).
    operating_rpm : (float, float) or None
        Minimum operating and maximum continuous speed, rpm: with ``model``, the critical speeds'
        API 617 separation margins are checked against them.
    limits : CriticalLimits
        What the critical speeds are verified by (API 684's by default).
    design : Path or None
        The controller design that was pushed (``controller design``): its prediction beside the
        stability measurement.
    balancing : Path or None
        A balancing record (``balance influence/correct/forces --record``): the unbalance, the
        correction masses and the ISO 21940-11 grade.
    """

    stability: Path | None = None
    runup: Recording | None = None
    coefficients: Path | None = None
    before: Recording | None = None
    after: Recording | None = None
    push_log: Path | None = None
    cmin_m: float | None = None
    model: str | None = None
    drops: list[Recording] = field(default_factory=list)
    operating_rpm: tuple[float, float] | None = None
    limits: CriticalLimits = CriticalLimits()
    design: Path | None = None
    balancing: Path | None = None


def machine_identity(recs: list[Recording]) -> dict:
    """The devices the session's recordings were made with, each once (kind, model, serial,
    firmware, the URLs it was reached by) with the recordings it is in, and when and where each
    recording was made. A device is told apart by its identity: its model and serial where it
    states a serial (the same CAN devices reached over another virtual bus in each run are one
    device), else its name and URL.

    Parameters
    ----------
    recs : list of Recording
        The session's recordings (run-up, before, after, the stability runs).
    """
    devices: dict[tuple, dict] = {}
    recordings = []
    for rec in recs:
        session = rec.session
        recordings.append({"recording": str(rec.path), "start_time": session.get("start_time", ""),
                           "ambdaq_version": session.get("ambdaq_version", ""), "host": session.get("host", "")})
        for d in rec.devices.values():
            ident = {k: v for k, v in d.identity.items() if k in IDENTITY_KEYS}
            key = (d.name, ident.get("model"), ident.get("serial")) if ident.get("serial") else (d.name, ident.get("url"))
            entry = devices.setdefault(key, {"device": d.name, **ident, "urls": [], "recordings": []})
            if ident.get("url") and ident["url"] not in entry["urls"]:
                entry["urls"].append(ident["url"])
            if rec.path.name not in entry["recordings"]:
                entry["recordings"].append(rec.path.name)
    return {"devices": list(devices.values()), "recordings": recordings}


@dataclass
class Commissioning:
    """What :func:`gather` found.

    Attributes
    ----------
    data : dict
        Everything the report's tables show, as plain data (``ambdaq report --json``):
        ``machine``, ``stability`` (rows and limits), ``vibration`` (bands and Cmin), ``runup``
        (the order tracking's range and 1X peaks), ``runout`` (before and after, per axis),
        ``push_log``, ``files``; a part whose files were not given is None.
    stability : StabilityDocument or None
        The results file, with its curves, for the figure.
    runup : RunupDiagnostics or None
        The run-up's order tracking, for the figures.
    apht : Apht or None
        The APHT of the recording after the push, for its figure.
    """

    data: dict
    stability: object | None
    runup: runup_diagnostics.RunupDiagnostics | None
    apht: Apht | None = None


def gather(files: SessionFiles) -> Commissioning:
    """Read and evaluate a session's files (see :class:`SessionFiles`)."""
    if not any((files.stability, files.runup, files.before, files.drops)):
        raise BadInputError("a report needs at least one of --stability, --runup, --before/--after or --drops")
    if (files.before is None) != (files.after is None):
        raise BadInputError("--before and --after go together: the runout check compares the two")
    doc = iso_stability.load_results(files.stability) if files.stability else None
    inputs = {r.path.resolve(): r for r in (files.runup, files.before, files.after, *files.drops) if r is not None}
    for run in doc.runs if doc else []:  # each once; runs moved away are not read
        path = Path(run.source.get("path") or "")
        if run.source.get("path") and path.is_file() and path.resolve() not in inputs:
            inputs[path.resolve()] = open_recording(path)
    out: dict = {"machine": machine_identity(list(inputs.values())) if inputs else None}
    out["stability"] = None if doc is None else {
        "file": str(files.stability), "limits_peak_gs": list(doc.limits_peak_gs), "min_coherence": doc.min_coherence,
        "rows": [{"speed_rpm": r.speed_rpm, "axis": r.axis, "peak": r.peak, "peak_db": r.peak_db, "peak_hz": r.peak_hz,
                  "coherence_at_peak": r.coherence_at_peak, "zone": r.zone, "reason": r.reason} for r in doc.runs]}
    notes: list[str] = []
    if files.runup:
        runup = with_rotor(files.runup, "a run-up's vibration zones and order tracking")  # read once for both
        grades, info = iso_vibration.evaluate([runup], cmin_m=files.cmin_m, band_rpm=5000.0,
                                              coefficients=files.coefficients)
        out["vibration"] = {**{k: info[k] for k in ("cmin_um", "cmin_from", "limits_ratio_cmin", "band_rpm",
                                                    "runout_removed")},
                            "bands": [g.as_dict() for g in grades]}
        diag = runup_diagnostics.analyse(runup, coefficients=files.coefficients, orders=(1, 2), model=files.model,
                                         operating_rpm=files.operating_rpm, limits=files.limits)
        notes += info["notes"] + diag.notes
        out["runup"] = {"rpm_from": round(float(diag.track.rpm.min()), 1), "rpm_to": round(float(diag.track.rpm.max()), 1),
                        "windows": int(diag.track.rpm.shape[0]), "compensation": diag.compensation,
                        "peaks_1x": diag.peaks_1x(),  # as runup --json gives them
                        "runout_removed": None if files.coefficients is None else RUNOUT_REMOVED,
                        "model": files.model, "model_basis": None if diag.modes is None else diag.modes.basis,
                        "critical_speeds": [c.as_dict() for c in diag.criticals]}
    else:
        diag = None
        out["vibration"] = out["runup"] = None
    if files.before:
        check = check_recordings(files.before, files.after, [1, 2])
        notes += check.notes
        out["runout"] = {"before": check.before, "after": check.after, "axes": check.axes}
        try:  # how the 1X moved through the run after the push (the LMS converging, a thermal bow)
            after = apht(files.after, coefficients=files.coefficients)
        except BadInputError as err:
            after = None
            notes.append(f"no APHT of the run after the push: {err}")
        out["apht"] = None if after is None else aphts(after, files.after)
    else:
        out["runout"] = out["apht"] = None
        after = None
    coef = None if files.coefficients is None else Coefficients.load(files.coefficients)
    out["coefficients"] = None if coef is None else pushed_runout(coef, files.coefficients)
    if coef is not None and (problem := held_unbalance(coef, files.coefficients.name)):
        notes.append(problem)  # at-speed coefficients used as runout: an open item, as identify warned
    out["touchdowns"] = touchdowns(files.drops) if files.drops else None
    out["push_log"] = push_log_entries(files.push_log,
                                       None if files.coefficients is None else {file_sha256(files.coefficients)})
    out["files"] = {k: str(v.path if isinstance(v, Recording) else v) for k, v in vars(files).items()
                    if isinstance(v, (Path, Recording))}
    if files.drops:
        out["files"]["drops"] = [str(r.path) for r in files.drops]
    out["controller"] = None if files.design is None else controller_section(files.design, doc)
    out["balancing"] = None if files.balancing is None else load_record(files.balancing)
    out["verdict"] = verdict(out, notes, pushed=files.coefficients is not None)
    return Commissioning(out, doc, diag, after)


def controller_section(path: Path, stability) -> dict:
    """The pushed controller design (issue 42): what ``controller design --json`` said of it, its
    prediction over speed, and each graded stability run beside the prediction at its speed."""
    from .controller_design import COMPARE_TOLERANCE_DB, compare, load_design

    design = load_design(path)
    runs = [] if stability is None else [(r.axis, r.speed_rpm, r.peak_db, r.zone) for r in stability.runs]
    return {"file": str(path), **design.summary, "tolerance_db": COMPARE_TOLERANCE_DB,
            "compared": compare(design, runs),
            "prediction": {"speeds_rpm": design.speeds_rpm.tolist(), "axes": design.axes,
                           "peak_db": [[None if np.isnan(v) else v for v in row] for row in design.peak_db],
                           "stock_peak_db": [[None if np.isnan(v) else v for v in row] for row in design.stock_peak_db]}}


def aphts(res: Apht, rec: Recording) -> dict:
    """The report's APHT table: per radial axis, the 1X of the gap (runout out where the
    coefficients were given) and of the command error in the first and the last window, as
    ``apht --json`` gives them (:meth:`~ambdaq.workflows.apht.Apht.first_last`)."""
    return {"recording": str(rec.path), "rpm": round(res.rpm, 1), "windows": int(res.time_s.shape[0]),
            "window_s": res.window_s, "compensation": res.compensation, "rows": res.first_last(1)}


def pushed_runout(coef: Coefficients, path: Path) -> dict:
    """The runout coefficient file ``path`` (loaded: ``coef``) pushes, per axis and harmonic, as
    ``runout identify --json`` printed it (:func:`~ambdaq.workflows.runout.runout_table`)."""
    return {"file": str(path), "method": coef.source.get("method", ""), "axes": runout_table(coef)}


def touchdowns(snapshots: list[Recording]) -> list[dict]:
    """Each snapshot file's rotor drop (ISO 14839-5), in the order given: the file, the first
    contact's time, and what :class:`~ambdaq.analysis.touchdown.Touchdown` says of it; ``drop`` is
    None for a file in which the rotor never reached its touchdown bearing."""
    rows = []
    for rec in snapshots:
        found = recorded_drop(rec.metadata)
        rows.append({"file": str(rec.path), "drop": None if found is None else {
            "contact": datetime.fromtimestamp(found.contact_ns / 1e9, timezone.utc).isoformat(),
            "cmin_um": round(found.cmin_m * 1e6, 3), **asdict(found.touchdown)}})
    return rows


ZONE_MEANING = {"A": "newly commissioned machines", "B": "unrestricted long-term operation",
                "C": "limited operation only", "D": "damage may occur"}  # ISO 14839-2/-3 zone descriptions


def verdict(data: dict, notes: list[str], *, pushed: bool) -> dict:
    """The report's first box: the worst zone of each standard with where it was found, the runout
    before and after on its worst axis, and the open items (zones C and D, axes not measured, data
    notes, parts of the session not given).

    Parameters
    ----------
    data : dict
        :func:`gather`'s tables (``stability``, ``vibration``, ``runout``, ``push_log``).
    notes : list of str
        What the evaluations noted about their inputs (samples lost within the limit ...).
    pushed : bool
        Whether a coefficient file was given (then its push must be in the log).
    """
    lines, open_items = [], []
    s = data["stability"]
    if s is None:
        open_items.append("no ISO 14839-3 stability measurement given (--stability)")
    else:
        graded = [r for r in s["rows"] if r["zone"]]
        for r in s["rows"]:
            if not r["zone"]:
                open_items.append(f"ISO 14839-3: {r['axis']} at {r['speed_rpm']:,.0f} rpm not measured: {r['reason']}")
        if graded:
            w = max(graded, key=lambda r: (r["zone"], r["peak"]))
            lines.append({"check": "stability margin", "standard": "ISO 14839-3", "zone": w["zone"],
                          "result": f"zone {w['zone']} ({ZONE_MEANING[w['zone']]}): worst {w['axis']} at "
                                    f"{w['speed_rpm']:,.0f} rpm, peak |Gs| {w['peak']:.2f} ({w['peak_db']:.1f} dB) "
                                    f"at {w['peak_hz']:,.0f} Hz"})
    v = data["vibration"]
    if v is None:
        open_items.append("no run-up given (--runup): no ISO 14839-2 vibration zones")
    elif v["bands"]:
        w = max(v["bands"], key=lambda b: b["ratio_cmin"])
        lines.append({"check": "vibration", "standard": "ISO 14839-2", "zone": w["zone"],
                      "result": f"zone {w['zone']} ({ZONE_MEANING[w['zone']]}): worst {w['bearing']} bearing "
                                f"{w['max_um']:.2f} µm = {w['ratio_cmin']:.3f} Cmin at {w['at_rpm']:,.0f} rpm "
                                f"(Cmin {v['cmin_um']:g} µm)"})
    u = data.get("runup")
    if u is not None and u.get("model"):
        checks = u["critical_speeds"]
        failed = [c for c in checks if not c["passed"]]
        lines.append({"check": "critical speeds", "standard": "API 684", "zone": None,
                      "result": (f"{len(checks) - len(failed)} of {len(checks)} verified against the {u['model']} model"
                                 if checks else f"the {u['model']} model predicts none inside the run")})
        for c in failed:
            open_items.append("API 684: critical speed " + (f"predicted at {c['predicted_rpm']:,.0f} rpm"
                                                            if c["predicted_rpm"] is not None else
                                                            f"measured at {c['measured_rpm']:,.0f} rpm") +
                              f" fails: {c['rule']}")
    c = data.get("controller")
    if c is not None:
        off = [x for x in c["compared"] if not x["within"]]
        lines.append({"check": "controller design", "standard": "ISO 14839-3 prediction", "zone": c.get("zone"),
                      "result": f"predicted zone {c.get('zone')} to {c['prediction']['speeds_rpm'][-1]:,.0f} rpm; "
                                f"{len(c['compared']) - len(off)} of {len(c['compared'])} measured peaks within "
                                f"{c['tolerance_db']:g} dB of the prediction"})
        open_items += [f"controller design: {x['axis']} at {x['speed_rpm']:,.0f} rpm measured {x['measured_db']:.2f} dB, "
                       f"predicted {x['predicted_db']:.2f} dB" for x in off]
        if not c["compared"]:
            open_items.append("controller design: no graded stability run to compare its prediction with (--stability)")
    for line in lines:
        if line["zone"] in ("C", "D"):
            open_items.append(f"{line['standard']}: zone {line['zone']}, {ZONE_MEANING[line['zone']]}")
    r = data["runout"]
    if r is None:
        open_items.append("no recordings before and after the push given (--before, --after)")
    else:
        worst = max(r["axes"].items(), key=lambda kv: kv[1]["harmonics"][0]["after_um"])
        h = worst[1]["harmonics"][0]
        lines.append({"check": "runout (command error 1X)", "standard": "Ro et al. runout feedforward", "zone": None,
                      "result": f"{worst[0]} {h['before_um']:.2f} -> {h['after_um']:.2f} µm ({h['change_db']:+.1f} dB), "
                                f"the worst axis after, at {r['after']['rpm']:,.0f} rpm"})
    b = data.get("balancing")
    if b is not None:
        masses = ", ".join(f"{m['plane']} {m['grams']:.4f} g at {m['deg']:.1f}°" for m in b["correction"])
        grade = ("no grade (the record has no maximum speed: --max-rpm)" if b["grade_mm_s"] is None else
                 f"{b['grade']} ({b['grade_mm_s']:.3g} ± {b['grade_std_mm_s']:.2g} mm/s at {b['max_rpm']:,.0f} rpm)")
        p = b["predicted_after"]
        after = "" if p is None else f"; predicted after it at most {p['at_most_mm_s']:.3g} mm/s ({p['grade']})"
        lines.append({"check": "rotor balance", "standard": "ISO 21940-11", "zone": None,
                      "result": f"{grade} at {b['rpm']:,.0f} rpm, by {b['method']}; correction {masses}{after}"})
        a = b.get("acceptance")
        if a is not None:  # the job asked for a grade (--grade): ISO 21940-14's acceptance
            lines.append({"check": f"rotor balance against {a['target']}", "standard": "ISO 21940-14", "zone": None,
                          "result": ("accepted after balancing" if a["after_balancing"] else
                                     "not accepted after balancing; within a user's check" if a["check"] else
                                     "not accepted") + f" ({b['grade_mm_s']:.3g} mm/s with an error of "
                                    f"{a['error_mm_s']:.2g} mm/s, permissible {a['permissible_mm_s']:g} mm/s)"})
    t = data.get("touchdowns")
    if t is not None:
        drops = [row["drop"] for row in t if row["drop"] is not None]
        worst = max(drops, key=lambda d: d["peak_ratio"], default=None)
        result = f"{len(drops)} drop{'s' * (len(drops) != 1)} in {len(t)} snapshot file{'s' * (len(t) != 1)}"
        if worst is not None:
            result += f"; worst {worst['peak_ratio']:.2f} Cmin at {worst['peak_at']}, {worst['whirl']} whirl"
        lines.append({"check": "rotor drops", "standard": "ISO 14839-5", "zone": None, "result": result})
        for row in t:
            d, name = row["drop"], Path(row["file"]).name
            if d is None:
                continue
            if not d["relevitated"]:
                open_items.append(f"ISO 14839-5: {name}: the rotor did not levitate again within the snapshot")
            if d["began_before"]:
                open_items.append(f"ISO 14839-5: {name}: the rotor was on its touchdown bearing when the snapshot "
                                  "began: its time on the bearing is a lower bound (record with a longer --pre)")
            if d["whirl"] == "backward":
                open_items.append(f"ISO 14839-5: {name}: backward whirl on the touchdown bearing: inspect it")
    if pushed and not data["push_log"]:
        open_items.append("the coefficient file is not in the push log: was it pushed from this host?")
    return {"lines": lines, "open_items": open_items + notes}


__all__ = ["Commissioning", "SessionFiles", "aphts", "gather", "machine_identity", "pushed_runout", "touchdowns",
           "verdict"]

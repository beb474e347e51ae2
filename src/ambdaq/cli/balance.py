"""``ambdaq balance``: the rotor balanced with its own bearings (issue 43)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from ..errors import BadInputError
from .options import plot_option


def _grade(_ctx, _param, value: str | None) -> float | None:
    """``--grade G2.5`` (or ``2.5``): the balance grade asked for, mm/s."""
    if value is None:
        return None
    try:
        g = float(value.strip().upper().removeprefix("G"))
    except ValueError:
        raise click.BadParameter(f"{value!r}: a balance grade, G2.5 or 2.5 (mm/s)") from None
    if not (g > 0 and g < float("inf")):
        raise click.BadParameter(f"{value!r}: a balance grade above 0 mm/s")
    return g


def _correction_options(command):
    """--holes, --max-rpm, --grade, --mass-tolerance, --angle-tolerance and --record: where the
    masses go, the grade's speed and the grade asked for, the masses' own errors, the job's record."""
    for option in (click.option("--mass-tolerance", type=click.FloatRange(min=0), default=0.0, show_default=True,
                                metavar="GRAMS",
                                help="The largest weighing error of each correction mass, g: counted in the grade "
                                     "predicted after the correction (ISO 21940-14; a radius off by dr as m dr / r)."),
                   click.option("--angle-tolerance", type=click.FloatRange(min=0, max=180), default=0.0,
                                show_default=True, metavar="DEG",
                                help="The largest error of the angle each correction mass is fitted at, degrees: "
                                     "counted in the grade predicted after the correction."),
                   click.option("--grade", "target", callback=_grade, metavar="G",
                                help="The balance grade asked for (ISO 21940-11, e.g. G2.5): the residual unbalance "
                                     "with its error judged against it (ISO 21940-14); needs --max-rpm."),
                   click.option("--record", type=click.Path(dir_okay=False),
                                help="Save the balancing record (sealed JSON): the runs and files it used, what "
                                     "--json prints (the correction masses, the grade)."),
                   click.option("--max-rpm", type=click.FloatRange(min=0, min_open=True),
                                help="The machine's maximum service speed, rpm: the balance grade (ISO 21940-11) of "
                                     "the unbalance the run holds is stated for it."),
                   click.option("--holes", type=click.IntRange(min=3, max=360),
                                help="Correction masses only in N holes per plane, evenly spaced from the "
                                     "key-phasor's mark: each plane's correction split between the two either side.")):
        command = option(command)
    return command


def _runout_option(what: str):
    """--coefficients FILE (the runout a slow roll identified, taken out of every run: ``what``) or
    --no-runout (none to take out): one of the two."""
    def decorate(command):
        command = click.option("--no-runout", is_flag=True,
                               help="No runout coefficients: the gaps' 1X taken as the rotor's (a machine whose "
                                    "sensors have no runout to speak of, as the simulated cone rig); warned.")(command)
        return click.option("--coefficients", type=click.Path(dir_okay=False),
                            help=f"Runout coefficients (runout identify of a slow roll): {what}")(command)
    return decorate


def _runout(coefficients: str | None, no_runout: bool) -> Path | None:
    """The runout coefficient file, or None with --no-runout (and a warning): exactly one of the two."""
    if (coefficients is None) == (not no_runout):
        raise BadInputError("give the runout coefficients of a slow roll (--coefficients FILE), or --no-runout if the "
                            "sensors have none: one of the two")
    if no_runout:
        click.echo("ambdaq: warning: --no-runout: the gaps' 1X is taken as the rotor's; a sensor runout would stay in "
                   "it and in the correction (runout identify of a slow roll takes it out)", err=True)
        return None
    return Path(coefficients)


def _max_grams_option(command):
    """--max-grams: the largest mass a plane takes."""
    return click.option("--max-grams", type=click.FloatRange(min=0, min_open=True),
                        help="The largest correction mass a plane takes, g (at its radius): where the least squares "
                             "asks more, the best correction with every plane within it.")(command)


@click.group("balance")
def command() -> None:
    """Balance the rotor: influence coefficients from a reference run and a trial run per plane, or
    the unbalance from one run's bearing forces."""


@command.command("influence")
@click.argument("reference", type=click.Path(dir_okay=False))
@click.argument("trials", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--mass", "masses", metavar="PLANE:GRAMS@DEG[:RADIUS_MM]", multiple=True, required=True,
              help="The trial mass of each trial run, in the runs' order (the spindle's planes: front, rear; the "
                   "cone's: upper, lower); at several speeds, the same for each.")
@_runout_option("the sensor runout, and what it drives through the loop, taken out of every run.")
@click.option("--machine", default="spindle", show_default=True,
              help="The machine model: its balancing planes and its loop's response to runout (machines/).")
@click.option("--signal", type=click.Choice(["gaps", "forces"]), default="gaps", show_default=True,
              help="What the influence coefficients are of: the gaps' 1X with the runout out (um), or the 1X force "
                   "each bearing applies (N: the coil currents and the position through the machine's force law; "
                   "the runs must record /amb/current). balance correct reads its runs as they were.")
@_correction_options
@_max_grams_option
@click.option("-o", "--output", type=click.Path(dir_okay=False),
              help="Save the influence coefficients (sealed JSON) for the next job: balance correct.")
@plot_option("Polar figure of the influence coefficients, the 1X now and predicted after, and the correction.")
@click.option("--overwrite", is_flag=True)
@click.option("--json", "as_json", is_flag=True, help="Print the influence coefficients and the correction as JSON.")
def influence(reference, trials, masses, coefficients, no_runout, machine, signal, holes, max_rpm, target,
              mass_tolerance, angle_tolerance, max_grams, output, record, plot_path, overwrite, as_json):
    """Influence coefficients of each balancing plane from REFERENCE and one run per plane with a
    trial mass on it (TRIALS, each with its --mass), all at one steady speed; the correction mass
    per plane that cancels the reference's 1X over the radial axes (least squares), and the
    residual 1X it predicts (ISO 21940-13's influence-coefficient method). At several speeds, the
    runs of each speed in turn (its reference, then its trial runs in the order of --mass): one
    least squares over every speed and axis.

    \b
    Examples:
      ambdaq balance influence ref.mcap t_front.mcap t_rear.mcap --mass front:0.1@0 --mass rear:0.1@0 \\
          --coefficients coef.json
      ambdaq balance influence ref20k.mcap tf20k.mcap tr20k.mcap ref30k.mcap tf30k.mcap tr30k.mcap \\
          --mass front:0.1@0 --mass rear:0.1@0 --coefficients coef.json
      ambdaq balance influence ref.mcap t_front.mcap t_rear.mcap --mass front:0.1@0 --mass rear:0.1@0 \\
          --coefficients coef.json --signal forces
    """
    from ..machines.balance_masses import BalanceMass
    from ..machines.models import loop_model
    from ..workflows.balancing import influence_balancing, run_vector

    _writable(record, overwrite, max_rpm, target)
    files, per_speed = [reference, *trials], 1 + len(masses)
    if len(files) % per_speed:
        raise BadInputError(f"{len(files)} runs and {len(masses)} --mass: per speed, a reference and one trial run per "
                            "trial mass")
    coef = _runout(coefficients, no_runout)
    model = loop_model(machine, {})
    if not model.balance_planes:
        raise BadInputError(f"the {machine} model has no balancing planes")
    parsed = [BalanceMass.parse(m, model.balance_planes, model.balance_radius_m) for m in masses]
    groups = [files[i:i + per_speed] for i in range(0, len(files), per_speed)]
    result = influence_balancing([(run_vector(ref, coef, machine, signal), [(m, run_vector(t, coef, machine, signal))
                                                                            for m, t in zip(parsed, rest)])
                                  for ref, *rest in groups], holes=holes or 0, max_rpm=max_rpm, max_grams=max_grams)
    _judged(result, target, mass_tolerance, angle_tolerance)
    if output:
        from ..workflows.balancing import save_influence

        save_influence(result, output, files, coef, overwrite=overwrite)
    runs = [run for ref, *rest in groups for run in
            [("reference", ref), *((f"trial {m.plane}:{m.grams:g}@{m.deg:g}:{m.radius_m * 1e3:g}", t)
                                   for m, t in zip(parsed, rest))]]
    _show(result, as_json)
    _keep(result, record, plot_path, runs, coef, machine, None, overwrite)
    if output:
        click.echo(f"-> {output}", err=True)


@command.command("correct")
@click.argument("runs", nargs=-1, required=True, type=click.Path(dir_okay=False), metavar="RUN...")
@click.option("--influence", "influence_file", type=click.Path(dir_okay=False), required=True,
              help="The influence coefficients an earlier balance influence saved (-o) for this machine and speed.")
@_runout_option("the sensor runout, and what it drives through the loop, taken out of each run.")
@click.option("--machine", default="spindle", show_default=True, help="The machine model (machines/).")
@_correction_options
@_max_grams_option
@plot_option("Polar figure of the influence coefficients, the 1X now and predicted after, and the correction.")
@click.option("--overwrite", is_flag=True)
@click.option("--json", "as_json", is_flag=True, help="Print the correction as JSON.")
def correct(runs, influence_file, coefficients, no_runout, machine, holes, max_rpm, target, mass_tolerance,
            angle_tolerance, max_grams, record, plot_path, overwrite, as_json):
    """The correction masses for RUN from saved influence coefficients: the next balancing job on the
    same machine at the same speed, one run instead of a reference and a trial run per plane (one
    run at each speed of influence coefficients saved from several). The runs are read as the
    coefficients were measured: the gaps, or the bearings' forces (balance influence --signal).

    \b
    Example:
      ambdaq balance correct today.mcap --influence influence.json --coefficients coef.json
    """
    from ..workflows.balancing import correct_with, influence_signal, run_vector

    _writable(record, overwrite, max_rpm, target)
    coef = _runout(coefficients, no_runout)
    signal = influence_signal(influence_file)
    result = correct_with(influence_file, [run_vector(run, coef, machine, signal) for run in runs],
                          holes=holes or 0, max_rpm=max_rpm, max_grams=max_grams, coefficients=coef)
    _judged(result, target, mass_tolerance, angle_tolerance)
    _show(result, as_json)
    _keep(result, record, plot_path, [("run", run) for run in runs], coef, machine, influence_file, overwrite)


@command.command("forces")
@click.argument("run", type=click.Path(dir_okay=False))
@_runout_option("the runout out of the gap, the rotor's motion left.")
@click.option("--machine", default="spindle", show_default=True,
              help="The machine model: its rigid rotor, its bearings' force law and balancing planes (machines/).")
@_correction_options
@click.option("--before", "before_record", type=click.Path(dir_okay=False),
              help="The balancing record (--record) of the run the correction since came from, with the same "
                   "runout coefficients: the part of its unbalance their slow roll holds is stated in the deviation.")
@click.option("--overwrite", is_flag=True)
@click.option("--json", "as_json", is_flag=True, help="Print the unbalance and the correction as JSON.")
def forces(run, coefficients, no_runout, machine, holes, max_rpm, target, mass_tolerance, angle_tolerance, before_record,
           record, overwrite, as_json):
    """The unbalance per balancing plane from ONE run at a steady speed, without a trial mass: the
    force each bearing applies at 1X (current gain x coil current + negative stiffness x position)
    and the rigid rotor's mass and inertia give the unbalance force on each plane. The feedforward
    may run (its currents are what the bearings apply).

    \b
    Example:
      ambdaq balance forces run.mcap --coefficients coef.json --max-rpm 60000 --record before.json
      ambdaq balance forces after.mcap --coefficients coef.json --max-rpm 60000 --before before.json
    """
    from ..workflows.balancing import force_balancing, record_unbalance

    _writable(record, overwrite, max_rpm, target)
    coef = _runout(coefficients, no_runout)
    earlier = _before(before_record, coef, machine) if before_record else None
    before = None if earlier is None else record_unbalance(earlier)
    result = force_balancing(run, coef, machine, holes=holes or 0, max_rpm=max_rpm, before=before)
    _judged(result, target, mass_tolerance, angle_tolerance)
    d = result.as_dict()
    if earlier is not None:
        d["before"] = _predicted_and_measured(earlier, d)
    # the slow roll's part (workflows.balancing.force_balancing): without --before, of the rotor as it is
    if coef is not None and before is None:
        click.echo("ambdaq: note: the runout coefficients' slow roll held the rotor's response to its unbalance then, "
                   "given back as the unbalance this run holds; if the rotor has been corrected since that slow roll, "
                   "pass --before with the record of the run the correction came from, or record a new slow roll "
                   "(docs/balancing.md, section 4)", err=True)
    if as_json:
        click.echo(json.dumps(d, indent=2))
    else:
        click.echo(f"{d['rpm']:,.0f} rpm, feedforward {'on' if d['feedforward'] else 'off'}; unbalance from the "
                   f"bearings' forces ({d['windows']} windows):")
        for p, u in d["unbalance_estimated"].items():
            click.echo(f"  {p:<6} {u['g_mm']:.4g} +- {u['std_g_mm']:.2g} g mm at {u['deg']:.1f} deg")
        for m in d["correction"]:
            click.echo(f"correction {m['plane']}: {m['grams']:.4g} g at {m['deg']:.1f} deg, {m['radius_mm']:g} mm")
        if d["grade_mm_s"] is not None:
            click.echo(f"balance grade now (ISO 21940-11, {d['max_rpm']:,.0f} rpm): {d['grade_mm_s']:.3g} +- "
                       f"{d['grade_std_mm_s']:.2g} mm/s ({d['grade']})")
        _show_acceptance(d)
        _show_prediction(d)
        if "before" in d:
            b = d["before"]
            if b["within_prediction"] is None:
                click.echo(f"{b['record']}'s prediction not compared: {b['why_not']}")
            else:
                p = b["predicted_after"]
                click.echo(f"{b['record']} predicted {p['grade_mm_s']:.2g} mm/s after its correction, at most "
                           f"{p['at_most_mm_s']:.2g} ({p['level'] * 100:.0f} %); measured now {b['measured_mm_s']:.2g} "
                           f"+- {b['measured_std_mm_s']:.2g} mm/s: {'within' if b['within_prediction'] else 'beyond'} "
                           "the prediction")
    _keep(result, record, None, [("run", run)], coef, machine, None, overwrite)


def _before(path: str, coefficients: Path | None, machine: str) -> dict:
    """The balancing record at ``path`` (:func:`~ambdaq.workflows.balancing.load_record`), refused
    where it is of another machine or of other runout coefficients than ``coefficients``."""
    from ..documents.coefficients import file_sha256
    from ..workflows.balancing import load_record

    rec = load_record(path)
    if rec["machine"] != machine:
        raise BadInputError(f"{path}: a balancing record of the {rec['machine']} machine, not the {machine}")
    if coefficients is not None and rec["runout_sha256"] != file_sha256(coefficients):
        raise BadInputError(f"{path}: its run's runout coefficients were not {coefficients}: their slow roll's part "
                            "of its unbalance is not the one these hold")
    return rec


def _predicted_and_measured(earlier: dict, d: dict) -> dict:
    """The grade the record ``earlier`` predicted after its correction beside the one measured now
    (``d``, this run's --json): issue 43's "predicted and then measured". Compared where both are
    stated at one maximum speed; otherwise why not."""
    p = earlier["predicted_after"]
    out = {"record": earlier["file"], "predicted_after": p, "measured_mm_s": d["grade_mm_s"],
           "measured_std_mm_s": d["grade_std_mm_s"], "within_prediction": None}
    if p is None:
        out["why_not"] = "the record states no grade predicted after its correction (no --max-rpm)"
    elif d["grade_mm_s"] is None or earlier["max_rpm"] != d["max_rpm"]:
        out["why_not"] = (f"the record's grade is at {earlier['max_rpm']:,.0f} rpm; give --max-rpm "
                          f"{earlier['max_rpm']:g} to compare")
    else:
        out["within_prediction"] = bool(d["grade_mm_s"] <= p["at_most_mm_s"])
    return out


def _show_acceptance(d: dict) -> None:
    """ISO 21940-14's verdict line, where --grade asked for one."""
    if "acceptance" not in d:
        return
    a = d["acceptance"]
    verdict = ("within it: accepted after balancing" if a["after_balancing"] else
               "not within it after balancing; a check of a balanced rotor would accept it" if a["check"] else
               "beyond it: not accepted")
    click.echo(f"against {a['target']} (ISO 21940-14): {d['grade_mm_s']:.3g} mm/s with an error of {a['error_mm_s']:.2g} "
               f"mm/s, {verdict}")


def _judged(result, target: float | None, mass_tolerance: float, angle_tolerance: float) -> None:
    """The grade asked for and the correction masses' own errors, on a result."""
    from ..workflows.balancing import MassTolerance

    result.target_mm_s = target
    result.tolerance = MassTolerance(mass_tolerance, angle_tolerance)


def _show_prediction(d: dict) -> None:
    """The grade predicted once the correction is on, where a grade is stated."""
    p = d.get("predicted_after")
    if p is None:
        return
    masses = (f"the masses within {p['mass_tolerance_g']:g} g and {p['angle_tolerance_deg']:g} deg"
              if p["mass_tolerance_g"] or p["angle_tolerance_deg"] else
              "the masses put on exactly: --mass-tolerance and --angle-tolerance count their errors")
    target = "" if "within_target" not in p else (
        f"; {'within' if p['within_target'] else 'not within'} {d['acceptance']['target']}")
    click.echo(f"predicted after the correction: {p['grade_mm_s']:.2g} mm/s, at most {p['at_most_mm_s']:.2g} mm/s "
               f"({p['level'] * 100:.0f} %, {p['grade']}{target}; the estimate's deviation, {masses})")
    if not p["improves"]:
        click.echo("ambdaq: warning: the correction is not predicted to lower the grade: the unbalance is within what "
                   "the estimate can tell, and its error would go on with the masses; leave them off", err=True)


def _writable(record: str | None, overwrite: bool, max_rpm: float | None = None, target: float | None = None) -> None:
    """Refuse before any work a --record that would replace a file without --overwrite, and a
    --grade without the speed it is judged at."""
    if target is not None and max_rpm is None:
        raise BadInputError("--grade judges the grade at the machine's maximum service speed: give --max-rpm too")
    if record:
        from ..output import check_output

        check_output(Path(record), overwrite, hint="choose another --record or pass --overwrite")


def _keep(result, record, plot_path, runs, coefficients, machine, influence_file, overwrite) -> None:
    """The sealed balancing record and the polar figure, where asked for."""
    if record:
        from ..workflows.balancing import save_record

        save_record(result, record, runs, coefficients, machine, influence_file, overwrite=overwrite)
    if plot_path:
        from ..figures import save
        from ..figures.balancing import draw_balancing

        save(draw_balancing(result), plot_path)
    for written in (record, plot_path):
        if written:
            click.echo(f"-> {written}", err=True)


def _show(result, as_json: bool) -> None:
    """The influence coefficients, the correction and the residual it predicts: JSON or lines."""
    if as_json:
        click.echo(json.dumps(result.as_dict(), indent=2))
        return
    d = result.as_dict()
    speeds = " and ".join(f"{r:,.0f}" for r in d.get("speeds_rpm", [d["rpm"]]))
    from ..workflows.balancing import SIGNALS

    unit = SIGNALS[result.signal][0]
    click.echo(f"{speeds} rpm{', feedforward on' if d['feedforward'] else ''}; influence coefficients"
               f"{' of the bearing forces' if result.signal == 'forces' else ''}, {unit} per g mm:")
    for plane, row in d[f"influence_{unit}_per_g_mm"].items():
        click.echo(f"  {plane:<6} " + "  ".join(f"{a} {v[unit]:.4f} @ {v['deg']:.1f}" for a, v in row.items()))
    for m in d["correction"]:
        click.echo(f"correction {m['plane']}: {m['grams']:.4g} g at {m['deg']:.1f} deg, {m['radius_mm']:g} mm"
                   + (" (with the trial masses taken off)" if result.trials else ""))
    if d["limited_by_max_grams"]:
        click.echo(f"held to {d['max_grams']:g} g: {', '.join(d['limited_by_max_grams'])} (the best correction within it)")
    click.echo(f"predicted residual 1X: {d['predicted_reduction'] * 100:.1f} % of the reference's")
    if d["grade_mm_s"] is not None:
        click.echo(f"balance grade now (ISO 21940-11, {d['max_rpm']:,.0f} rpm, the unbalance this run holds): "
                   f"{d['grade_mm_s']:.3g} +- {d['grade_std_mm_s']:.2g} mm/s ({d['grade']})")
        _show_acceptance(d)
        _show_prediction(d)

"""``ambdaq push``: download a coefficient file into a controller, verified (docs/push.md).

The sequence, over either port (serial or CANopen SDO):

1. read the controller's bank status (axes, harmonics, active bank and its device-computed CRC);
2. build the bank image from the coefficient file and validate it against that target: finite
   values, ranges, axes and harmonics that exist, an LMS schedule stable on the convergence map;
3. ``--dry-run`` stops here and prints the difference from the active bank;
4. unlock with the key, write the inactive bank, read back the CRC-32 the device computed over it
   and compare it with ours;
5. commit with that CRC: the controller switches at a control-period boundary;
6. read back the status and the active bank byte for byte, and log the push locally.

Any failure before the commit leaves the active bank untouched (writes only reach the inactive
one); a commit whose answer is lost is resolved by reading the status.

Every push keeps the bank it replaced, byte for byte, beside the log (``banks/CRC.bin``), and its
log entry names it: :func:`rollback` puts it back through the same steps 4-6 (``push --rollback``),
and is itself undone the same way.
"""

from __future__ import annotations

import json
import math
import os
import socket
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..documents.coefficients import Coefficients, file_sha256, fir_array, now_iso
from ..drivers.coefbank import BankImage, crc32
from ..drivers.interfaces import UNLOCK_KEY_ENV
from ..errors import BadInputError, DeviceError, DeviceTimeout
from ..units import phasor_um_deg

MAX_MAP_POINTS = 20_000  # convergence-map points a schedule may check: 8 harmonics x 0..60,000 rpm x 2 bearings is 9,600
STATE_ENV = "AMBDAQ_STATE_DIR"


def local_log_path() -> Path:
    """Where pushes are logged on this machine: ``$AMBDAQ_STATE_DIR/push.log`` or
    ``~/.local/state/ambdaq/push.log`` (JSON lines)."""
    base = os.environ.get(STATE_ENV) or Path.home() / ".local" / "state" / "ambdaq"
    return Path(base) / "push.log"


def append_local_log(entry: dict) -> Path:
    path = local_log_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as fh:
        fh.write(json.dumps(entry, sort_keys=True) + "\n")
    return path


LOG_KEYS = ("host_time", "bank", "crc32", "file", "file_sha256", "target", "host", "effective_sample", "outcome",
            "replaced_crc32", "replaced_image")


def push_log_entries(path: Path | None, file_sha256s: set[str] | None = None) -> list[dict]:
    """The push log's entries (``path``, default this machine's; none if there is none), only those
    of the coefficient files with these SHA-256s if given.

    Parameters
    ----------
    path : Path, optional
        A push log (JSON lines); one line, exit 2, if given and missing or not a push log.
    file_sha256s : set of str, optional
        Keep the pushes of these files only.
    """
    log = path if path is not None else local_log_path()
    if not log.exists():
        if path is not None:
            raise BadInputError(f"{path}: no such push log")
        return []
    entries = []
    for n, line in enumerate(log.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            entry = json.loads(line)
        except json.JSONDecodeError:
            raise BadInputError(f"{log}: line {n} is not JSON: not a push log") from None
        if not isinstance(entry, dict):
            raise BadInputError(f"{log}: line {n} is not an entry: not a push log")
        if file_sha256s is None or entry.get("file_sha256") in file_sha256s:
            entries.append({k: entry.get(k) for k in LOG_KEYS})
    return entries


def image_from(coef: Coefficients, status: dict, *, source_sha256: str, where: str) -> BankImage:
    """The bank image for ``coef`` on the controller described by ``status``; BadInputError says
    what does not fit.

    Parameters
    ----------
    coef : Coefficients
        The loaded (checksum-verified) coefficient file.
    status : dict
        The controller's bank status (``axes``: names, ``harmonics``: how many it runs).
    source_sha256 : str
        Hex SHA-256 of the coefficient file, stored in the image.
    where : str
        The file's name, for messages.
    """
    axes, n_harm = list(status["axes"]), int(status["harmonics"])
    missing = [a for a in coef.weights if a not in axes]
    if missing:
        raise BadInputError(f"{where}: axis {missing[0]!r} does not exist on the controller (it has {', '.join(axes)})")
    too_high = [k for k in coef.harmonics if not 1 <= k <= n_harm]
    if too_high:
        raise BadInputError(f"{where}: harmonic {too_high[0]}X is not run by the controller (1X..{n_harm}X)")
    w = np.zeros((len(axes), n_harm, 2))
    for axis, rows in coef.weights.items():
        for k, pair in zip(coef.harmonics, rows):
            w[axes.index(axis), k - 1] = pair
    # rows of 3 or 4 numbers (checked when the file was read): harmonic 0 is every harmonic
    rows = [tuple(map(float, r)) if len(r) == 4 else (0.0, *map(float, r)) for r in coef.lms_schedule]
    phase, bin_hz = None, 10.0
    if coef.lms_phase:
        bin_hz = float(coef.lms_phase["bin_hz"])
        table = coef.lms_phase["phase_rad"]
        missing = [a for a in table if a not in axes]
        if missing:
            raise BadInputError(f"{where}: lms_phase axis {missing[0]!r} does not exist on the controller")
        bins = {len(v) for v in table.values()}
        if len(bins) != 1:
            raise BadInputError(f"{where}: lms_phase rows differ in length")
        phase = np.zeros((len(axes), bins.pop()))
        for axis, vals in table.items():
            phase[axes.index(axis)] = vals
    fir, fir_rate = _fir_for(coef, status, where)
    mode = "lms" if rows else ("table" if coef.weights else "off")
    image = BankImage(w, mode, rows, source_sha256, phase, bin_hz, fir, fir_rate)
    problem = image.problem(len(axes), n_harm)
    if problem:
        raise BadInputError(f"{where}: {problem}")
    if rows:
        _check_schedule(rows, n_harm, coef.lms_plant or "bearings", phase, bin_hz, tuple(axes), where)
    return image


def _check_schedule(rows: list[tuple[float, ...]], n_harm: int, plant: str, phase: np.ndarray | None,
                    bin_hz: float, axes: tuple[str, ...], where: str) -> None:
    """BadInputError unless the LMS schedule ``rows`` is stable on the convergence map of ``plant``
    (Ro et al. Fig. 5), its loops standing for the controller's ``axes``.  The map needs
    scipy.signal and the rig's linearisation: imported here, so a push without a schedule and
    ``controller status`` start without them."""
    from dataclasses import replace

    from ..analysis.lms import PhaseTable, StateSpaceLoop, schedule_problem
    from ..machines.models import design_models
    from .plants import DESIGN_MACHINE, analysing, resolve_plant

    models = design_models(DESIGN_MACHINE)
    if plant not in models.plants:  # a plant the user gave stands for this controller's axes
        models = replace(models, axes=axes)
    loops = resolve_plant(plant, models)
    for name, (_loop, names) in loops.items():
        if not set(names) <= set(axes):
            raise BadInputError(f"{where}: its LMS schedule was designed on plant {plant!r}, whose {name} loop "
                                f"stands for {', '.join(names)}; the controller has {', '.join(axes)}")
    state_space = any(isinstance(loop, StateSpaceLoop) for loop, _ in loops.values())  # an eigenproblem per speed
    step = 250.0 if state_space else 100.0
    points = sum(max(0, math.ceil((hi - max(lo, step / 2)) / step)) * (n_harm if k == 0 else 1)
                 for k, lo, hi, mu in rows if mu != 0) * len(loops)
    if points > MAX_MAP_POINTS:
        raise BadInputError(f"{where}: the LMS schedule asks for {points:,} points of the convergence map to check; "
                            f"at most {MAX_MAP_POINTS:,} (fewer or narrower rows)")
    with analysing(plant):
        problem = schedule_problem(rows, n_harm, loops, None if phase is None else PhaseTable(phase, bin_hz, axes),
                                   rpm_step=step)
    if problem:
        raise BadInputError(f"{where}: LMS schedule is not stable: {problem}")


def _fir_for(coef: Coefficients, status: dict, where: str) -> tuple[np.ndarray | None, float]:
    """The file's base-motion FIR in the controller's plane order, checked against what it runs."""
    if not coef.fir:
        return None, 0.0
    spec = status.get("fir")
    if spec is None:
        raise BadInputError(f"{where}: holds a base-motion FIR; this controller runs no FIR feedforward")
    taps, rate = fir_array(coef, list(spec["planes"]), where)
    if taps.shape[1:3] != (spec["outputs"], spec["inputs"]) or taps.shape[3] > spec["max_taps"]:
        raise BadInputError(f"{where}: the FIR is {taps.shape}; the controller runs {len(spec['planes'])} planes x "
                            f"{spec['outputs']} x {spec['inputs']} x at most {spec['max_taps']} taps")
    if rate != float(spec["sample_rate_hz"]):
        raise BadInputError(f"{where}: the FIR runs at {rate:g} Hz, the controller at {spec['sample_rate_hz']:g} Hz")
    return taps, rate


def _phasor(w: np.ndarray) -> str:
    """[sin, cos] weights as amplitude (um) and phase (degrees)."""
    um, deg = phasor_um_deg(w)
    return f"{um:7.3f} um {deg:7.1f} deg"


def describe_difference(old: BankImage, new: BankImage, axes: list[str], tol_m: float = 1e-9) -> list[str]:
    """Lines saying how ``new`` differs from ``old``: mode, each changed weight (um, degrees), schedule."""
    out = []
    if old.mode != new.mode:
        out.append(f"mode: {old.mode} -> {new.mode}")
    n = max(old.weights.shape[1], new.weights.shape[1])
    ow = np.zeros((len(axes), n, 2))
    nw = np.zeros((len(axes), n, 2))
    ow[:, : old.weights.shape[1]] = old.weights
    nw[:, : new.weights.shape[1]] = new.weights
    for a, axis in enumerate(axes):
        for k in range(n):
            if np.max(np.abs(ow[a, k] - nw[a, k])) > tol_m:
                out.append(f"{axis:<8} {k + 1}X: {_phasor(ow[a, k])} -> {_phasor(nw[a, k])}")
    if (old.phase_rad is None) != (new.phase_rad is None) or (
            new.phase_rad is not None and not np.allclose(old.phase_rad, new.phase_rad, atol=1e-6)):
        out.append(f"lms phase compensation: {'none' if old.phase_rad is None else 'table'} -> "
                   f"{'none' if new.phase_rad is None else f'table of {new.phase_rad.shape[1]} bins'}")
    if (old.fir_taps is None) != (new.fir_taps is None) or (
            new.fir_taps is not None and (old.fir_taps.shape != new.fir_taps.shape
                                          or not np.allclose(old.fir_taps, new.fir_taps, rtol=0, atol=1e-12))):
        before = "none" if old.fir_taps is None else f"{old.fir_taps.shape[3]} taps"
        after = "none" if new.fir_taps is None else f"{new.fir_taps.shape[3]} taps"
        out.append(f"base-motion FIR: {before} -> {after}")
        if new.fir_taps is not None:
            out += [f"  plane {p} u{j + 1} <- d{m + 1}: " + " ".join(f"{t:+.5f}" for t in new.fir_taps[p, j, m])
                    for p in range(new.fir_taps.shape[0]) for j in range(new.fir_taps.shape[1])
                    for m in range(new.fir_taps.shape[2])]
    if list(map(tuple, old.schedule)) != list(map(tuple, new.schedule)):
        out.append(f"lms schedule: {len(old.schedule)} rows -> {len(new.schedule)} rows")
        out += [f"  {'all' if k == 0 else f'{k:g}X':>4} {lo:7.0f} .. {hi:7.0f} rpm  mu {mu:+g}" for k, lo, hi, mu in new.schedule]
    if new.pid is not None and (old.pid is None or not np.array_equal(old.pid, new.pid)):
        for a, axis in enumerate(axes):
            before = "-" if old.pid is None else " ".join(f"{g:g}" for g in old.pid[a])
            out.append(f"{axis:<8} PID (P, I, D): {before} -> {' '.join(f'{g:g}' for g in new.pid[a])}")
    old_bq = None if old.biquads is None else old.biquads
    if new.biquads is not None and (old_bq is None or old_bq.shape != new.biquads.shape
                                    or not np.array_equal(old_bq, new.biquads)):
        passing = np.array([1.0, 0.0, 0.0, 0.0, 0.0])
        for a, axis in enumerate(axes):
            used = [s for s in new.biquads[a] if not np.array_equal(s, passing)]
            out.append(f"{axis:<8} sections: {len(used)} (" + "; ".join(" ".join(f"{c:+.6g}" for c in s) for s in used) + ")")
    if old.source_sha256 != new.source_sha256:
        out.append(f"source: {old.source_sha256[:12] or '-'} -> {new.source_sha256[:12]}")
    return out or ["no difference: the controller already holds these coefficients"]


@dataclass
class PushResult:
    """What a push did: the image's CRC, the bank now active, the first sample run with it."""

    crc32: str
    bank: int
    effective_sample: int
    log: Path | None
    already_active: bool = False


@dataclass
class PushPlan:
    """A coefficient file checked against a controller: what would be written and where."""

    path: Path
    sha256: str
    status: dict
    image: BankImage


def plan_push(port, path: str | Path, coef: Coefficients) -> PushPlan:
    """Validate the coefficient file at ``path`` (loaded as ``coef``) against the controller behind
    ``port`` (its bank status); nothing is written."""
    path = Path(path)
    sha = file_sha256(path)
    status = port.bank_status()
    return PushPlan(path, sha, status, image_from(coef, status, source_sha256=sha, where=str(path)))


def plan_controller_push(port, path: str | Path, design) -> PushPlan:
    """Validate a controller design file (``controller design``, loaded as ``design``) against the
    controller behind ``port``: its axes by name, and the bank image that holds the active bank's
    feedforward as it is (its weights, mode, schedule, phase table and FIR read back from the
    controller) with the design's PID and sections; nothing is written.  A design that did not meet
    its target (exit 1 of ``controller design``) is refused."""
    from dataclasses import replace

    path = Path(path)
    if not design.meets_target:
        raise BadInputError(f"{path}: the design did not meet its target (controller design said why): not pushed")
    sha = file_sha256(path)
    status = port.bank_status()
    axes = list(status["axes"])
    if sorted(axes) != sorted(design.axes):
        raise BadInputError(f"{path}: the design is for axes {', '.join(design.axes)}, the controller has "
                            f"{', '.join(axes)}")
    order = [design.axes.index(a) for a in axes]
    active = BankImage.decode(port.read_bank("active", status["active_length"]))
    image = replace(active, pid=design.pid[order], biquads=design.biquads[order], source_sha256=sha)
    problem = image.problem(len(axes), int(status["harmonics"]))
    if problem:
        raise BadInputError(f"{path}: {problem}")
    return PushPlan(path, sha, status, image)


def keep_image(data: bytes) -> Path:
    """Keep a bank image beside the push log, named by its CRC-32 (the same image once)."""
    path = local_log_path().parent / "banks" / f"{crc32(data):08x}.bin"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_bytes(data)
        tmp.replace(path)
    return path


def _download(port, data: bytes, key: str, record: dict, target: str, status: dict, outcome: str) -> PushResult:
    """Steps 4-6 for ``data``: keep what the active bank holds, write the inactive bank, check the
    device's CRC-32, commit, read back byte for byte, and log with ``record`` (what was replaced
    named in it)."""
    crc = f"{crc32(data):08x}"
    if status["active_crc32"] == crc:
        return PushResult(crc, status["active_bank"], -1, None, already_active=True)
    replaced = port.read_bank("active", status["active_length"])
    if f"{crc32(replaced):08x}" != status["active_crc32"]:
        raise DeviceError(f"{target}: the active bank reads back with CRC-32 {crc32(replaced):08x}, but the "
                          f"controller states {status['active_crc32']}: nothing written")
    record = {**record, "replaced_crc32": status["active_crc32"], "replaced_image": str(keep_image(replaced))}
    try:
        port.unlock(key)
        port.write_bank(data)
        held = port.bank_status()
        if held["inactive_crc32"] != crc or held["inactive_length"] != len(data):
            raise DeviceError(f"{target}: read-back CRC-32 of the inactive bank is {held['inactive_crc32']} "
                              f"({held['inactive_length']} bytes), expected {crc} ({len(data)} bytes): not committed")
        try:
            effective = port.commit_bank(int(crc, 16), record)
        except DeviceTimeout:
            effective = -1  # the answer was lost: the status says whether the switch happened
        final = port.bank_status()
        if final["active_crc32"] != crc:
            raise DeviceError(f"{target}: after the commit the active bank holds CRC-32 {final['active_crc32']}, not {crc}")
        if port.read_bank("active", len(data)) != data:
            raise DeviceError(f"{target}: the active bank does not read back byte for byte")
    except DeviceError as err:
        append_local_log({**record, "crc32": crc, "outcome": f"failed: {err}"})
        raise
    log = append_local_log({**record, "crc32": crc, "outcome": outcome, "bank": final["active_bank"],
                            "effective_sample": effective})
    return PushResult(crc, final["active_bank"], effective, log)


def push(port, plan: PushPlan, key: str, *, target: str) -> PushResult:
    """Download a planned image through ``port`` (a controller driver) and commit.

    Parameters
    ----------
    port : ControllerDriver or CanopenController
        The open controller the plan was made on.
    plan : PushPlan
        From :func:`plan_push`.
    key : str
        The controller's unlock key.
    target : str
        The device URL, for the logs.
    """
    record = {"host_time": now_iso(), "file": plan.path.name, "file_sha256": plan.sha256, "target": target,
              "host": socket.gethostname()}
    return _download(port, plan.image.encode(), key, record, target, plan.status, "committed")


@dataclass
class RollbackPlan:
    """What ``push --rollback`` would put back: the image the last push to the target replaced,
    the log entry of that push and the controller's status."""

    image: bytes
    last: dict
    status: dict


def plan_rollback(port, target: str) -> RollbackPlan:
    """The bank the last push to ``target`` (this machine's log) replaced, checked: the controller
    must still run what that push wrote, and the kept image must be the one replaced (its
    CRC-32); BadInputError (nothing written) otherwise."""
    log = local_log_path()
    done = [e for e in push_log_entries(None) if e.get("target") == target
            and e.get("outcome") in ("committed", "rolled back")]
    if not done:
        raise BadInputError(f"no push to {target} in {log}: nothing to roll back")
    last = done[-1]
    if not last.get("replaced_image"):
        raise BadInputError(f"the last push to {target} ({last.get('file')}, {last.get('host_time')}) was logged "
                            "before pushes kept what they replaced: it cannot be rolled back")
    status = port.bank_status()
    if status["active_crc32"] != last["crc32"]:
        raise BadInputError(f"{target} runs CRC-32 {status['active_crc32']}, not {last['crc32']} that the last push "
                            f"from this machine wrote ({last.get('file')}, {last.get('host_time')}): something else "
                            "changed it since; nothing written")
    try:
        image = Path(last["replaced_image"]).read_bytes()
    except OSError as err:
        raise BadInputError(f"the bank the last push replaced is gone: {err}") from None
    if f"{crc32(image):08x}" != last["replaced_crc32"]:
        raise BadInputError(f"{last['replaced_image']}: CRC-32 {crc32(image):08x}, not the {last['replaced_crc32']} "
                            "the controller ran: the kept image is damaged; nothing written")
    return RollbackPlan(image, last, status)


def rollback(port, plan: RollbackPlan, key: str, *, target: str) -> PushResult:
    """Put back the bank the last push replaced (:func:`plan_rollback`), through the same write,
    CRC check, commit and byte-for-byte read-back as a push; logged, and undone the same way."""
    record = {"host_time": now_iso(), "file": f"rollback of {plan.last.get('file', '?')}",
              "file_sha256": "", "target": target, "host": socket.gethostname()}
    return _download(port, plan.image, key, record, target, plan.status, "rolled back")


def resolve_key(key: str | None, rig_key: str | None) -> str:
    """The unlock key: ``--key``, else ``$AMBDAQ_UNLOCK_KEY``, else the rig file's ``unlock_key``."""
    found = key or os.environ.get(UNLOCK_KEY_ENV) or rig_key
    if not found:
        raise BadInputError(f"no unlock key: pass --key, set {UNLOCK_KEY_ENV}, or give unlock_key in the rig file "
                            "(the simulated controller's default is in docs/push.md)")
    return found

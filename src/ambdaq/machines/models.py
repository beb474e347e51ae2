"""A machine's models, by name: its closed loop's modes (``runup --model NAME``) and the loops its
LMS feedforward is designed on (``lms --plant``).  A machine with such a model is one module here
and one line in :data:`MODELS`; the simulator's rigs step the same models."""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from ..errors import BadInputError

MODELS = {  # machine -> the module with its loop_model (and LMS, where it has design loops)
    "spindle": "ambdaq.machines.spindle_loop",
    "cone": "ambdaq.machines.cone",
}


@dataclass(frozen=True)
class LoopModel:
    """A rotordynamic model's closed loop, with the controller gains it was built at.

    Attributes
    ----------
    at : callable
        ``at(rpm)`` (rpm): the loop's lightly damped modes there, as frequencies (Hz), damping
        ratios and whirl (+1 forward, -1 backward, 0 not known), each an array sorted by frequency.
    basis : str
        Which controller gains it holds, in words (the recording's own, or the model's defaults).
    assumed : bool
        The gains are the model's defaults, not what the recording says its controller ran.
    response : callable or None
        ``response(rpm)`` (rpm): the rotor's steady 1X there from the model's own unbalance and
        runout, a phasor (m) per bearing axis by name (API 684's unbalance response analysis);
        None: the model does not give it.
    runout_response : callable or None
        ``runout_response(rpm, runout)``: the rotor's steady 1X that a 1X sensor runout (a phasor
        per axis by name, m) drives through the loop, per axis by name (m); None: not given.
    balance_planes : tuple of str
        The rotor's balancing planes (empty: none modelled).
    balance_radius_m : float
        The radius of their holes, m.
    plane_unbalance : callable or None
        ``plane_unbalance(rpm, position, current)``: the unbalance per balancing plane (kg m) that
        the rotor's 1X position (phasors per bearing axis by name, m) and coil currents (per
        current channel by name, A) imply, from the rotor's model and its bearings' force law
        alone; None: not given.
    bearing_force : callable or None
        ``bearing_force(rpm, position, current)``: the 1X force each bearing axis's magnets put on
        the rotor (N, per axis by name), from the same force law; None: not given.
    inertia_force : callable or None
        ``inertia_force(rpm, position)``: the force per bearing axis (N) that moves the rigid
        rotor through a 1X position (m, per axis by name): what the bearings apply to follow a
        motion no unbalance drives (a runout's); None: not given.
    axes : tuple of str
        The bearing axes the model knows, by the names its recordings give them.
    currents : tuple of str
        The current channels ``plane_unbalance`` reads (``/amb/current``'s fields).
    """

    at: Callable[[float], tuple[np.ndarray, np.ndarray, np.ndarray]]
    basis: str
    assumed: bool
    response: Callable[[float], dict[str, complex]] | None = None
    runout_response: Callable[[float, Mapping[str, complex]], dict[str, complex]] | None = None
    balance_planes: tuple[str, ...] = ()
    balance_radius_m: float = 0.0
    plane_unbalance: Callable[[float, Mapping[str, complex], Mapping[str, complex]], np.ndarray] | None = None
    axes: tuple[str, ...] = ()
    currents: tuple[str, ...] = ()
    bearing_force: Callable[[float, Mapping[str, complex], Mapping[str, complex]], dict[str, complex]] | None = None
    inertia_force: Callable[[float, Mapping[str, complex]], dict[str, complex]] | None = None

    def require(self, machine: str, path: object, axes: list[str], currents: tuple[str, ...] = ()) -> None:
        """BadInputError unless every one of ``axes`` (a recording's radial axes) and ``currents``
        (its current channels, where the forces are asked for) is one the model knows: a model
        read on another machine's recording would see no motion where it looks, and say so with
        numbers."""
        for kind, given, known in (("axes", axes, self.axes), ("current channels", currents, self.currents)):
            unknown = [a for a in given if a not in known]
            if unknown:
                raise BadInputError(f"{path}: its {kind} ({', '.join(given) or 'none'}) are not the {machine} model's "
                                    f"({', '.join(known)}): is --machine {machine} this recording's machine?")


def loop_model(machine: str, calibration: Mapping[str, str]) -> LoopModel:
    """The loop of ``machine`` at the controller gains ``calibration`` states (its model's own
    where it states none); BadInputError naming the machines that have one."""
    if machine not in MODELS:
        raise BadInputError(f"--model {machine!r}: the models known here are the machines' ({', '.join(MODELS)})")
    return importlib.import_module(MODELS[machine]).loop_model(calibration)


def design_models(machine: str):
    """The LMS design models of ``machine`` (:class:`~ambdaq.analysis.lms.DesignModels`); one line
    if it has none."""
    models = getattr(importlib.import_module(MODELS[machine]), "LMS", None) if machine in MODELS else None
    if models is None:
        raise BadInputError(f"the {machine} machine has no LMS design models: give --plant ss:FILE with its loop")
    return models

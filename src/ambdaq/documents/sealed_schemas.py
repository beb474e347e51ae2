"""The shapes and ranges of the sealed documents (the coefficient, frequency-response and
compensator points files), checked before anything uses them (docs/coefficients.md).

A document comes from ambdaq, but it travels: it is mailed, edited, kept for years. So every
value is checked for type and range once, here, and a file that fails says where in one line
(``coef.json: lms_schedule.0.2: Input should be less than or equal to 500000``), exit 2, before
a controller is opened.  The bounds also bound the work a file can ask for: the convergence
map's speed grid is at most MAX_RPM / 100 rpm steps per row and harmonic.

pydantic (v2) rather than jsonschema: the checks are the Python types the loader wants
(tuples of finite floats, bounded lists, dicts of them), strict (no "1.5" taken for 1.5), and
its errors carry the path to the offending key.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from ..drivers.coefbank import MU_LIMIT
from ..errors import BadInputError

MAX_HARMONIC = 64  # the controllers run 8; a runout beyond 64X is below any sensor's resolution
MAX_RPM = 500_000.0  # the fastest AMB machines run below 200,000 rpm
MAX_ROWS = 1_000  # LMS schedule rows
MAX_AXES = 64
MAX_PHASE_BINS = 100_000
MAX_TAPS = 10_000
MAX_FREQUENCIES = 1_000_000

Finite = Annotated[float, Field(strict=True, allow_inf_nan=False)]
Rpm = Annotated[float, Field(strict=True, ge=0, le=MAX_RPM, allow_inf_nan=False)]
Mu = Annotated[float, Field(strict=True, ge=-MU_LIMIT, le=MU_LIMIT, allow_inf_nan=False)]
Harmonic = Annotated[int, Field(strict=True, ge=1, le=MAX_HARMONIC)]
Name = Annotated[str, Field(strict=True, min_length=1, max_length=64)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Runout(_Strict):
    units: Literal["m"]
    harmonics: Annotated[list[Harmonic], Field(max_length=MAX_HARMONIC)]
    weights: Annotated[dict[Name, Annotated[list[tuple[Finite, Finite]], Field(max_length=MAX_HARMONIC)]],
                       Field(max_length=MAX_AXES)]

    @model_validator(mode="after")
    def _one_pair_per_harmonic(self) -> "Runout":
        for axis, rows in self.weights.items():
            if len(rows) != len(self.harmonics):
                raise ValueError(f"{axis} has {len(rows)} weight pairs for {len(self.harmonics)} harmonics")
        return self


class Phase(_Strict):
    bin_hz: Annotated[float, Field(strict=True, gt=0, le=1e5, allow_inf_nan=False)]
    phase_rad: Annotated[dict[Name, Annotated[list[Finite], Field(max_length=MAX_PHASE_BINS)]],
                         Field(max_length=MAX_AXES)]


class Fir(_Strict):
    sample_rate_hz: Annotated[float, Field(strict=True, gt=0, le=1e7, allow_inf_nan=False)]
    unit: str = "V/(m/s^2)"
    outputs: Annotated[list[Name], Field(max_length=MAX_AXES)] = []
    inputs: Annotated[list[Name], Field(max_length=MAX_AXES)] = []
    planes: Annotated[dict[Name, Annotated[list[list[Annotated[list[Finite], Field(max_length=MAX_TAPS)]]],
                                           Field(max_length=MAX_AXES)]], Field(max_length=MAX_AXES)]


Row3 = tuple[Rpm, Rpm, Mu]
Row4 = tuple[Annotated[int, Field(strict=True, ge=0, le=MAX_HARMONIC)], Rpm, Rpm, Mu]


class CoefficientDocument(_Strict):
    """A coefficient file's content (its format, version and checksum already checked)."""

    format: str
    version: int
    target: dict = Field(default_factory=dict)
    source: dict = Field(default_factory=dict)
    runout: Runout
    lms_schedule: Annotated[list[Row3 | Row4], Field(max_length=MAX_ROWS)] = Field(default_factory=list)
    lms_phase: Phase | None = None
    lms_plant: Annotated[str, Field(max_length=4096)] = ""
    fir: Fir | None = None

    @field_validator("lms_phase", "fir", mode="before")
    @classmethod
    def _empty_is_none(cls, value):
        return None if value == {} else value

    @field_validator("lms_schedule")
    @classmethod
    def _rows_run_up(cls, rows):
        for i, row in enumerate(rows):
            if row[-3] >= row[-2]:
                raise ValueError(f"row {i}: rpm_from {row[-3]:g} is not below rpm_to {row[-2]:g}")
        return rows


Spectrum = Annotated[list[Finite], Field(max_length=MAX_FREQUENCIES)]


class Response(_Strict):
    re: Spectrum
    im: Spectrum
    # coherence is at most 1; the estimate's last bits may pass it by a rounding, not by a millionth
    coherence: Annotated[list[Annotated[float, Field(strict=True, ge=0, le=1 + 1e-6, allow_inf_nan=False)]],
                         Field(max_length=MAX_FREQUENCIES)]


class Column(_Strict):
    source: dict = Field(default_factory=dict)
    outputs: Annotated[dict[Name, Response], Field(max_length=MAX_AXES)]


class FrequencyResponseDocument(_Strict):
    """A frequency-response file's content (docs/frf.md)."""

    format: str
    version: int
    input_topic: str = ""
    output_topic: str = ""
    unit: str = ""
    freq_hz: Annotated[list[Annotated[float, Field(strict=True, ge=0, allow_inf_nan=False)]],
                       Field(max_length=MAX_FREQUENCIES)]
    columns: Annotated[dict[Name, Column], Field(max_length=MAX_AXES)]

    @model_validator(mode="after")
    def _one_value_per_frequency(self) -> "FrequencyResponseDocument":
        n = len(self.freq_hz)
        for name, col in self.columns.items():
            for out, r in col.outputs.items():
                if not len(r.re) == len(r.im) == len(r.coherence) == n:
                    raise ValueError(f"columns.{name}.outputs.{out} has {len(r.re)} re, {len(r.im)} im and "
                                     f"{len(r.coherence)} coherence values for {n} frequencies")
        return self


class Phasors(_Strict):
    re: Spectrum
    im: Spectrum


class PointsDocument(_Strict):
    """A compensator points file's content (docs/base-motion.md)."""

    format: str
    version: int
    unit: str = ""
    freq_hz: Annotated[list[Annotated[float, Field(strict=True, gt=0, allow_inf_nan=False)]],
                       Field(max_length=MAX_FREQUENCIES)]
    planes: Annotated[dict[Name, dict[Literal["W11", "W12", "W21", "W22"], Phasors]], Field(max_length=MAX_AXES)]
    residual: list[list[Finite]] = Field(default_factory=list)
    source: dict = Field(default_factory=dict)

    @model_validator(mode="after")
    def _one_value_per_frequency(self) -> "PointsDocument":
        n = len(self.freq_hz)
        for plane, ws in self.planes.items():
            for w, p in ws.items():
                if not len(p.re) == len(p.im) == n:
                    raise ValueError(f"planes.{plane}.{w} has {len(p.re)} re and {len(p.im)} im values for {n} "
                                     "frequencies")
        return self


MaybeFinite = Annotated[float | None, Field(strict=True, allow_inf_nan=False)]
Zone = Literal["A", "B", "C", "D"]


class StabilityCurves(_Strict):
    freq_hz: Annotated[list[Annotated[float, Field(strict=True, ge=0, allow_inf_nan=False)]], Field(max_length=MAX_FREQUENCIES)]
    coherence: list[Annotated[float, Field(strict=True, ge=0, le=1, allow_inf_nan=False)]]
    gs_real: list[MaybeFinite]
    gs_imag: list[MaybeFinite]
    gc_real: list[MaybeFinite]
    gc_imag: list[MaybeFinite]
    go_real: list[MaybeFinite]
    go_imag: list[MaybeFinite]

    @model_validator(mode="after")
    def _one_value_per_frequency(self) -> "StabilityCurves":
        n = len(self.freq_hz)
        for name in ("coherence", "gs_real", "gs_imag", "gc_real", "gc_imag", "go_real", "go_imag"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"{name} has {len(getattr(self, name))} values for {n} frequencies")
        return self


class StabilityRun(_Strict):
    axis: Name
    speed_rpm: Rpm
    source: dict[Name, Annotated[str, Field(max_length=4096)]]
    segments: Annotated[int, Field(strict=True, ge=1)]
    peak: Annotated[float | None, Field(strict=True, ge=0, allow_inf_nan=False)]
    peak_db: MaybeFinite
    peak_hz: Annotated[float | None, Field(strict=True, ge=0, allow_inf_nan=False)]
    coherence_at_peak: Annotated[float | None, Field(strict=True, ge=0, le=1, allow_inf_nan=False)]
    band_hz: tuple[Finite, Finite]
    zone: Zone | None
    reason: Annotated[str, Field(max_length=1000)]
    synchronous_bins_skipped_hz: Annotated[list[Finite], Field(max_length=MAX_FREQUENCIES)]
    curves: StabilityCurves

    @model_validator(mode="after")
    def _graded_or_told_why(self) -> "StabilityRun":
        if (self.zone is None) == (self.reason == ""):
            raise ValueError("a run has a zone or the reason it has none, not both or neither")
        return self


class StabilityDocument(_Strict):
    """``ambdaq-iso-stability`` version 1 (``ambdaq iso stability -o``)."""

    format: Literal["ambdaq-iso-stability"]
    version: Literal[1]
    standard: Literal["ISO 14839-3"]
    limits_peak_gs: tuple[Finite, Finite, Finite]
    min_coherence: Annotated[float, Field(strict=True, ge=0, le=1, allow_inf_nan=False)]
    resolution_hz: Annotated[float, Field(strict=True, gt=0, allow_inf_nan=False)]
    runs: Annotated[list[StabilityRun], Field(min_length=1, max_length=10_000)]


def check_document(model: type[BaseModel], doc: dict, path):
    """``doc`` (a sealed document's JSON) checked against ``model``; the first problem as one
    BadInputError line naming the key (``runout.weights.front_x.0.1: ...``)."""
    try:
        return model.model_validate(doc)
    except ValidationError as err:
        first = err.errors()[0]
        where = ".".join(str(p) for p in first["loc"] if not str(p).startswith(("tuple[", "function-")))
        raise BadInputError(f"{path}: {where or 'document'}: {first['msg']}") from None

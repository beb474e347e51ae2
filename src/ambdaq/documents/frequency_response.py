"""The frequency-response file: what ``ambdaq frf estimate`` writes and the designs read.

A JSON document (docs/frf.md), versioned and checksummed like the coefficient file::

    {"format": "ambdaq-frf", "version": 1,
     "input_topic": "/amb/ff", "output_topic": "/amb/error", "unit": "m/m",
     "freq_hz": [0.0, 10.0, ...],
     "columns": {"front_x": {"source": {"path", "sha256", "speed_rpm", "segments"},
                             "outputs": {"front_x": {"re": [...], "im": [...], "coherence": [...]}, ...}},
                 ...},
     "checksum": "crc32:xxxxxxxx"}

One column per excited input axis; each holds the response of every output axis to it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import BadInputError
from .sealed import read_sealed, seal, write_sealed
from ..roles import ERROR, FF

FORMAT = "ambdaq-frf"
VERSION = 1


@dataclass
class FrequencyResponse:
    """Measured responses H[output, input](f) with their coherence (see the module docstring).

    Attributes
    ----------
    freq_hz : ndarray, shape (n,)
        Frequencies, in Hz.
    columns : dict
        Input axis -> {"source": dict, "outputs": {output axis -> (H complex (n,), coherence (n,))}}.
    input_topic, output_topic, unit : str
        What was measured: from ``input_topic`` to ``output_topic``, in ``unit``.
    """

    freq_hz: np.ndarray
    columns: dict
    input_topic: str = FF
    output_topic: str = ERROR
    unit: str = "m/m"

    def response(self, output: str, input_: str) -> tuple[np.ndarray, np.ndarray]:
        """(H, coherence) from ``input_`` to ``output`` over ``freq_hz``; BadInputError if not measured."""
        try:
            return self.columns[input_]["outputs"][output]
        except KeyError:
            raise BadInputError(f"the frequency response has no {input_} -> {output} (inputs measured: "
                                f"{', '.join(self.columns) or 'none'})") from None

    def to_dict(self) -> dict:
        cols = {}
        for name, col in self.columns.items():
            cols[name] = {"source": col["source"], "outputs": {
                out: {"re": h.real.tolist(), "im": h.imag.tolist(), "coherence": c.tolist()}
                for out, (h, c) in col["outputs"].items()}}
        doc = {"format": FORMAT, "version": VERSION, "input_topic": self.input_topic,
               "output_topic": self.output_topic, "unit": self.unit, "freq_hz": self.freq_hz.tolist(),
               "columns": cols}
        return seal(doc)

    def save(self, path: str | Path, *, overwrite: bool = False) -> Path:
        return write_sealed(path, self.to_dict(), overwrite=overwrite)

    @classmethod
    def load(cls, path: str | Path) -> "FrequencyResponse":
        """Read and check a frequency-response file: format, version, checksum, shapes, finite values."""
        from .sealed_schemas import FrequencyResponseDocument, check_document

        path = Path(path)
        doc = read_sealed(path, FORMAT, VERSION, "frequency-response file")
        check_document(FrequencyResponseDocument, doc, path)  # types, ranges, lengths: one line naming the key
        try:
            freq = np.array(doc["freq_hz"], dtype=float)
            columns = {}
            for name, col in doc["columns"].items():
                outs = {}
                for out, v in col["outputs"].items():
                    h = np.array(v["re"], dtype=float) + 1j * np.array(v["im"], dtype=float)
                    c = np.array(v["coherence"], dtype=float)
                    if freq.ndim != 1 or h.shape != freq.shape or c.shape != freq.shape:
                        raise ValueError(f"{name} -> {out} has {h.size} points for {freq.size} frequencies")
                    outs[out] = (h, c)
                columns[name] = {"source": dict(col.get("source", {})), "outputs": outs}
        except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as err:
            raise BadInputError(f"{path}: malformed frequency response ({err})") from None
        values = [freq] + [x for col in columns.values() for pair in col["outputs"].values() for x in pair]
        if not all(np.all(np.isfinite(v)) for v in values):
            raise BadInputError(f"{path}: the frequency response holds a value that is not a finite number")
        return cls(freq, columns, str(doc.get("input_topic", "")), str(doc.get("output_topic", "")),
                   str(doc.get("unit", "")))

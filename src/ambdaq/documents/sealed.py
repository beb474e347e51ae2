"""Sealed JSON documents: versioned and checksummed, as the coefficient file, the frequency-response
file and the compensator points file are.

A document carries ``"format"`` and ``"version"``, and ``"checksum": "crc32:xxxxxxxx"``, the CRC-32
of its canonical JSON (sorted keys, no spaces) without the checksum. A file edited by hand, of
another format or version, or not JSON, is refused in one line (BadInputError, exit 2); so is
what is not a regular file (a FIFO would block the read forever), a file above MAX_BYTES, JSON
nested deeper than Python's parser goes and an integer longer than it converts.
"""

from __future__ import annotations

import json
import stat
import zlib
from pathlib import Path

from ..errors import BadInputError
from ..output import check_output

MAX_BYTES = 64 * 2**20  # the largest sealed document ambdaq writes is well under 1 MiB


def canonical_json(doc: dict) -> bytes:
    """The bytes a document's checksum covers: sorted keys, no spaces."""
    return json.dumps(doc, sort_keys=True, separators=(",", ":")).encode()


def _checksum(doc: dict) -> str:
    return f"crc32:{zlib.crc32(canonical_json(doc)):08x}"


def seal(doc: dict) -> dict:
    """``doc`` with its checksum (last), computed over everything else; sealing twice changes nothing."""
    body = {k: v for k, v in doc.items() if k != "checksum"}
    return {**body, "checksum": _checksum(body)}


def write_sealed(path: str | Path, doc: dict, *, overwrite: bool = False, indent: int | None = None) -> Path:
    """Write ``seal(doc)`` to ``path``; refuses to replace a file unless ``overwrite``."""
    path = Path(path)
    check_output(path, overwrite)
    path.write_text(json.dumps(seal(doc), indent=indent) + "\n")
    return path


def read_sealed(path: str | Path, fmt: str, version: int, what: str) -> dict:
    """Read a sealed document and check its format, version and checksum; returns it without the
    checksum. ``what`` names the file in messages (``"coefficient file"`` ...)."""
    path = Path(path)
    doc = read_json(path, what)
    if not isinstance(doc, dict) or doc.get("format") != fmt:
        raise BadInputError(f"{path}: not an ambdaq {what} (format must be {fmt!r})")
    if doc.get("version") != version:
        raise BadInputError(f"{path}: {what} version {doc.get('version')!r}; this ambdaq reads {version}")
    if doc.pop("checksum", None) != _checksum(doc):
        raise BadInputError(f"{path}: checksum mismatch: the file was changed after it was written")
    return doc


def check_regular_file(path: Path, what: str) -> None:
    """BadInputError unless ``path`` is a regular file of at most MAX_BYTES (a FIFO would block
    the read forever, a device or a huge file would not end)."""
    try:
        info = path.stat()
    except FileNotFoundError:
        raise BadInputError(f"{path}: no such {what}") from None
    except OSError as err:
        raise BadInputError(f"{path}: cannot read the {what} ({err.strerror})") from None
    if not stat.S_ISREG(info.st_mode):
        raise BadInputError(f"{path}: not a regular file; a {what} is a file")
    if info.st_size > MAX_BYTES:
        raise BadInputError(f"{path}: {info.st_size:,} bytes; a {what} is at most {MAX_BYTES:,}")


def read_json(path: Path, what: str):
    """The JSON value in the regular file ``path`` of at most MAX_BYTES; one line otherwise."""
    check_regular_file(path, what)
    try:
        return json.loads(path.read_text())
    except RecursionError:
        raise BadInputError(f"{path}: not a {what}: JSON nested too deep") from None
    except (OSError, ValueError, UnicodeDecodeError) as err:  # ValueError: also an integer too long to read
        raise BadInputError(f"{path}: not a JSON {what} ({err})") from None

"""Where a command may write a file: a new path, or with ``--overwrite`` a regular file, and never
anything else (a FIFO, a device node, a directory, or a symlink to one): replacing those had
turned a FIFO into a file and, as root, ``-o /dev/full`` into one."""

from __future__ import annotations

import os
import stat
from pathlib import Path

from .errors import BadInputError

KINDS = {stat.S_IFDIR: "a directory", stat.S_IFIFO: "a FIFO", stat.S_IFCHR: "a character device",
         stat.S_IFBLK: "a block device", stat.S_IFSOCK: "a socket"}


def check_output(path: Path, overwrite: bool, *, hint: str = "choose another -o or pass --overwrite") -> Path:
    """``path``, if a file may be written there: nothing is there, or a regular file is and
    ``overwrite`` says to replace it; otherwise one BadInputError line (exit 2).

    Parameters
    ----------
    path : Path
        The output file.
    overwrite : bool
        Whether an existing regular file may be replaced.
    hint : str
        What the user can do about an existing file.
    """
    try:
        mode = os.stat(path).st_mode  # through a symlink: a link to a device is the device
    except FileNotFoundError:
        if os.path.islink(path):
            raise BadInputError(f"{path} is a symlink to nothing: ambdaq writes regular files only") from None
        return path
    except OSError as err:
        raise BadInputError(f"{path}: {err.strerror or err}") from None
    if not stat.S_ISREG(mode):
        kind = KINDS.get(stat.S_IFMT(mode), "not a regular file")
        via = " (through a symlink)" if os.path.islink(path) else ""
        raise BadInputError(f"{path} is {kind}{via}: ambdaq writes regular files only, with or without --overwrite")
    if not overwrite:
        raise BadInputError(f"{path} exists: {hint}")
    return path

"""Objects named ``"module:attribute"``: one way to load what a registry names (a back-end, a
device driver, a rig profile, a command), imported only when asked for."""

from __future__ import annotations

import importlib


def load_object(target: str, package: str | None = None):
    """The attribute a ``"module:attribute"`` target names, its module imported now.

    Parameters
    ----------
    target : str
        ``"package.module:Attribute"``; a module relative to ``package`` may start with a dot.
    package : str, optional
        The package relative module names are resolved against.
    """
    module, sep, attr = target.partition(":")
    if not sep or not module or not attr:
        raise ValueError(f"{target!r} is not 'module:attribute'")
    return getattr(importlib.import_module(module, package), attr)


__all__ = ["load_object"]

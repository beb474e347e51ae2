"""``ambdaq record --status``: the live view (:mod:`ambdaq.live.view`) drawn on the terminal with rich."""

from __future__ import annotations

from ..acquisition.recorder import Progress
from ..live.view import BearingStatus


def status_table(p: Progress, previous: Progress | None, bearings: list[BearingStatus]):
    """The rich renderable of one redraw: the recording's line, a row per device, a row per bearing.

    Parameters
    ----------
    p, previous : Progress
        This report and the one before it (for the rates over the last interval).
    bearings : list of BearingStatus
    """
    from rich.console import Group
    from rich.table import Table

    size = f"{p.file_bytes / 1e6:,.1f} MB"
    split = "" if p.next_split_s is None else f"   next file in {p.next_split_s:,.1f} s"
    devices = Table(title=f"recording {p.elapsed_s:,.1f} s   {size}{split}", title_justify="left")
    for col in ("device", "samples/s", "samples", "drops", "duplicates"):
        devices.add_column(col, justify="left" if col == "device" else "right")
    for name, c in p.devices.items():
        before = previous.devices.get(name) if previous is not None else None
        dt = p.elapsed_s - previous.elapsed_s if previous is not None else p.elapsed_s
        rate = (c.samples - (before.samples if before else 0)) / dt if dt > 0 else 0.0
        devices.add_row(name, f"{rate:,.0f}", f"{c.samples:,d}", f"{c.drops:,d}", f"{c.duplicates:,d}")
    parts = [devices]
    if bearings:
        table = Table()
        for col in ("bearing", "rpm", "gap DC x / y [µm]", "1X x / y [µm]"):
            table.add_column(col, justify="left" if col == "bearing" else "right")
        for b in bearings:
            one_x = "–" if b.one_x_um is None else f"{b.one_x_um[0]:.2f} / {b.one_x_um[1]:.2f}"
            table.add_row(f"{b.device} {b.bearing}", "–" if b.speed_rpm is None else f"{b.speed_rpm:,.0f}",
                          f"{b.dc_um[0]:.2f} / {b.dc_um[1]:.2f}", one_x)
        parts.append(table)
    return Group(*parts)


__all__ = ["status_table"]

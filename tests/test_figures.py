"""What the figures show, read back from them: no tick labels on top of each other, titles and
legends inside the figure and off the data they would hide, the traces that must be visible
visible. Each figure is drawn by the function its command calls and rendered (Agg) before it is
measured, since text extents exist only once drawn."""

from __future__ import annotations

import numpy as np
import pytest

from ambdaq.figures import pyplot
from ambdaq.daq import load, open_recording

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)


def overlapping_tick_labels(ax) -> list[tuple[str, str]]:
    """Pairs of visible tick labels on one axis whose boxes intersect."""
    renderer = ax.figure.canvas.get_renderer()
    out = []
    for axis in (ax.xaxis, ax.yaxis):
        labels = [t for t in axis.get_ticklabels() if t.get_visible() and t.get_text()]
        boxes = [t.get_window_extent(renderer) for t in labels]
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                if boxes[i].overlaps(boxes[j]):
                    out.append((labels[i].get_text(), labels[j].get_text()))
    return out


def titles_inside(fig) -> list[str]:
    """Titles of panels whose box leaves the figure, or runs into another panel's title."""
    renderer = fig.canvas.get_renderer()
    page = fig.get_window_extent(renderer)
    boxes = [(ax.title.get_text(), ax.title.get_window_extent(renderer)) for ax in fig.axes if ax.title.get_text()]
    bad = [t for t, b in boxes if b.x0 < page.x0 - 1 or b.x1 > page.x1 + 1]
    bad += [f"{a} / {c}" for i, (a, b) in enumerate(boxes) for c, d in boxes[i + 1:] if b.overlaps(d)]
    return bad


@pytest.fixture(scope="module")
def ten_seconds(tmp_path_factory):
    from click.testing import CliRunner

    from ambdaq.cli.main import cli

    out = tmp_path_factory.mktemp("fig") / "ten.mcap"
    r = CliRunner().invoke(cli, ["sim", "generate", "--rpm", "30000", "--duration", "10", "-q", "-o", str(out)])
    assert r.exit_code == 0, r.output
    return out


@pytest.mark.parametrize("window", [(None, None), (1.0, 1.02)])
def test_plot_of_ten_seconds_and_of_20_ms_reads(ten_seconds, window, run_cli, tmp_path):
    """10 s at 10 kHz: the time panel is the envelope (at most two points per bin), not 100,000
    points drawn into a band; a 20 ms window is the waveform, its time ticks in ms from the
    window's start, none on top of another; every title inside the figure."""
    from ambdaq.figures.signal import ENVELOPE_BINS, draw_signal

    start, end = window
    out = tmp_path / "p.png"
    args = ["plot", ten_seconds, "--field", "front_x", "-o", out]
    if start is not None:
        args += ["--start", str(start), "--end", str(end)]
    r = run_cli(*args)
    assert r.exit_code == 0, r.output
    assert out.stat().st_size > 30_000
    rec = load(ten_seconds, topics=["/amb/gap", "/amb/rotor"], start=start, end=end)
    fig = draw_signal(rec, "/amb/gap", "front_x", 150e-6)
    try:
        fig.canvas.draw()
        time_ax = fig.axes[0]
        drawn = sum(len(line.get_xdata()) for line in time_ax.get_lines())
        if start is None:
            assert drawn <= ENVELOPE_BINS and len(time_ax.collections) == 1  # the mean line and the min-max band
            assert "envelope of 100,000 samples" in time_ax.title.get_text()
            # the band holds every sample: its extremes are the signal's
            band = time_ax.collections[0].get_paths()[0].vertices[:, 1]
            y = rec["/amb/gap"]["front_x"] * 1e6
            assert band.max() == pytest.approx(y.max()) and band.min() == pytest.approx(y.min())
        else:
            assert drawn == len(rec["/amb/gap"]) == 201 and time_ax.get_xlabel().startswith("time [ms] from 1")
        for ax in fig.axes:
            assert overlapping_tick_labels(ax) == [], ax.get_title()
        assert titles_inside(fig) == []
    finally:
        pyplot().close(fig)


@pytest.mark.parametrize("field", ["rear_x", "rear_y"])
def test_the_orbit_is_the_bearings_x_across_and_y_up_whichever_field_is_asked(ten_seconds, field):
    """The orbit panel draws the bearing's x horizontally and its y vertically for either field of
    the bearing (asked for rear_y it had put rear_y across: the orbit mirrored, its whirl
    reversed); its axis labels and title say so."""
    from ambdaq.figures.signal import draw_signal

    rec = load(ten_seconds, topics=["/amb/gap", "/amb/rotor"], start=1.0, end=1.05)
    fig = draw_signal(rec, "/amb/gap", field, None)
    try:
        orbit = fig.axes[2]
        (line,) = orbit.get_lines()
        gap = rec["/amb/gap"]
        np.testing.assert_array_equal(line.get_xdata(), gap["rear_x"] * 1e6)
        np.testing.assert_array_equal(line.get_ydata(), gap["rear_y"] * 1e6)
        assert orbit.get_xlabel().startswith("rear_x") and orbit.get_ylabel().startswith("rear_y")
        assert orbit.get_title() == "orbit: rear_x across, rear_y up"
    finally:
        pyplot().close(fig)


def _boxes_overlap(a, b) -> bool:
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


def test_runout_identification_figure_shows_x_and_y_and_keeps_its_legend_off_the_angles(ten_seconds, tmp_path):
    """Each bearing's x and y are told apart (solid filled x under dashed open y), the phasor legend
    covers no angle label of any polar plot, and the orbit's second trace is not called "after":
    nothing has been pushed when runout is identified."""
    from ambdaq.figures.runout import draw_identification
    from ambdaq.workflows.runout import identify_recordings

    ident = identify_recordings([open_recording(ten_seconds)], [1, 2, 3, 4], "fit")
    fig = draw_identification(ident)
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        polar = [ax for ax in fig.axes if ax.name == "polar"]
        assert len(polar) == 4
        legends = [lg for sub in fig.subfigs for lg in sub.legends]
        assert legends, "the phasor legend"
        for ax in polar:
            angle_labels = [t for t in ax.xaxis.get_ticklabels() if t.get_visible() and t.get_text()]
            assert any("225" in t.get_text() for t in angle_labels)
            for legend in legends:
                box = legend.get_window_extent(renderer)
                hit = [t.get_text() for t in angle_labels if _boxes_overlap(box, t.get_window_extent(renderer))]
                assert hit == [], hit
        one_x = polar[0]
        marks = {ln.get_label(): ln for ln in one_x.get_lines() if not ln.get_label().startswith("_")}
        for bearing in ("front", "rear"):
            x, y = marks[f"{bearing}_x"], marks[f"{bearing}_y"]
            assert (x.get_marker(), y.get_marker()) == ("o", "s") and y.get_markerfacecolor() == "none"
            assert y.get_zorder() > x.get_zorder() and x.get_markersize() > y.get_markersize()
        orbit_labels = [t.get_text() for ax in fig.axes for lg in [ax.get_legend()] if lg for t in lg.get_texts()
                        if "sensor" in t.get_text()]
        assert orbit_labels and not any("after" in label for label in orbit_labels), orbit_labels
        assert titles_inside(fig) == []
    finally:
        pyplot().close(fig)


def test_selfsense_figure_has_the_convergence_region_and_one_legend_entry_each(tmp_path):
    """Several speeds with --sweep: panel (a) is one file's two angles (two legend entries, not a
    pair per file), (b) names each file once, and the last panel is the convergence region: the
    final error against the initial one beside the Lyapunov bound, as the docs promise."""
    from click.testing import CliRunner

    from ambdaq.cli.main import cli
    from ambdaq.figures.selfsense import draw_selfsense
    from ambdaq.workflows.selfsense import analyse

    files = []
    for rpm in ("100", "400", "1000"):
        f = tmp_path / f"ls_{rpm}.mcap"
        r = CliRunner().invoke(cli, ["sim", "generate", "--profile", "lorentz", "--rpm", rpm, "--duration", "1.5", "-q",
                                     "-o", str(f)])
        assert r.exit_code == 0, r.output
        files.append(str(f))
    overrides = {"resistance": None, "inductance": None, "emf_constant": None}
    results = [analyse(open_recording(f), 8.0, 0.5, overrides, sweep=(f == files[0])) for f in files]
    fig = draw_selfsense(results)
    try:
        fig.canvas.draw()
        a, b, c, region = fig.axes
        assert [t.get_text() for t in a.get_legend().get_texts()] == ["encoder", "estimate"]
        assert len(a.get_lines()) == 2
        labels = [t.get_text() for t in b.get_legend().get_texts()]
        assert labels == [f"ls_{rpm}.mcap" for rpm in ("100", "400", "1000")]
        assert "convergence region" in region.get_title()
        sweep = results[0]["sweep"]
        (span,) = region.patches  # the Lyapunov bound, shaded: its corners in data x, axes y
        corners = span.get_patch_transform().transform(span.get_path().vertices)[:, 0]
        lo, hi = sweep["lyapunov_deg"]
        assert corners.min() == pytest.approx(lo) and corners.max() == pytest.approx(hi)
        plotted = sum(len(line.get_xdata()) for line in region.get_lines())
        assert plotted == len(sweep["initial_deg"])  # every initial error tried is on it
        for ax in fig.axes:
            assert overlapping_tick_labels(ax) == []
        assert titles_inside(fig) == []
    finally:
        pyplot().close(fig)


def test_model_region_legend_hides_none_of_the_region(run_cli, tmp_path):
    """The legend stands beside the (Kp, Kd) map: it covers none of the axes, so no stable gain."""
    from ambdaq.workflows.cone_axis import EXAMPLE, load_axis
    from ambdaq.figures.model import draw_region
    from ambdaq.analysis.cone import stable_region

    axis = tmp_path / "axis.toml"
    axis.write_text(EXAMPLE)
    loop, _magnet = load_axis(str(axis))
    region = stable_region(loop)
    fig = draw_region(loop, region, region.kp_max(loop))
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        (ax,) = fig.axes[:1]
        legend, panel = ax.get_legend().get_window_extent(renderer), ax.get_window_extent(renderer)
        assert not _boxes_overlap(legend, panel)
        assert legend.x1 <= fig.get_window_extent(renderer).x1 + 1  # and inside the figure
        assert [t.get_text() for t in ax.get_legend().get_texts()][0] == "design point"
        assert overlapping_tick_labels(ax) == [] and titles_inside(fig) == []
    finally:
        pyplot().close(fig)


def test_full_spectrum_parts_forward_and_backward_whirl_as_the_true_orbit_has_them(tmp_path, run_cli):
    """The full spectrum of the simulator's true rotor orbit at the front bearing (30,000 rpm): at +1X
    and -1X it shows the radii of the forward and backward circles that the orbit's 1X ellipse is
    made of (from the harmonic fit of x and y: (b_x + a_y) + j(b_y - a_x) and (b_x - a_y) + j(a_x +
    b_y), halved), within 1 %; the unbalance response whirls forward. plot draws it as its fourth
    panel, forward and backward either side of zero."""
    from ambdaq.analysis.runout import harmonic_fit
    from ambdaq.analysis.spectrum import full_spectrum
    from ambdaq.figures.signal import draw_signal

    rec_path = tmp_path / "truth.mcap"
    assert run_cli("sim", "generate", "--rpm", "30000", "--duration", "1.05", "--truth", "-q", "-o",
                   rec_path).exit_code == 0
    rec = load(rec_path, start=0.05)  # past the simulated rig's start-up
    pos, theta = rec["/truth/position"], rec["/amb/rotor"]["angle"]
    n = 10000  # 1 s: 500 Hz falls on a bin
    x, y = pos["front_x"][:n], pos["front_y"][:n]
    f, a = full_spectrum(x, y, fs=10000.0)
    px, py = harmonic_fit(np.column_stack([x, y]), theta[:n], (1,))[0]
    forward = abs(complex(px.imag + py.real, py.imag - px.real)) / 2
    backward = abs(complex(px.imag - py.real, px.real + py.imag)) / 2
    at = {k: a[np.argmin(np.abs(f - k * 500.0))] for k in (1, -1)}
    # within 1 % of the orbit (the backward circle is a few nm: an isotropic rotor's unbalance
    # response is nearly circular, and at that size the rotor's noise-driven motion shows)
    assert abs(at[1] - forward) < 0.01 * forward and abs(at[-1] - backward) < 0.01 * forward
    assert at[1] > 100 * at[-1]  # the unbalance response whirls forward
    fig = draw_signal(rec, "/amb/gap", "front_x", 150e-6)
    try:
        fig.canvas.draw()
        panel = fig.axes[3]
        assert "full spectrum of front" in panel.get_title()
        lo, hi = panel.get_xlim()
        assert lo < -500 < 500 < hi  # both directions shown, with the +-1X marks
        assert titles_inside(fig) == [] and all(overlapping_tick_labels(ax) == [] for ax in fig.axes)
    finally:
        pyplot().close(fig)


def test_the_rotors_speed_is_plotted_in_rpm(spindle_file):
    """``plot`` of /amb/rotor's speed: rpm on the axis, the recorded rad/s scaled (30,000 rpm)."""
    from ambdaq.daq import load
    from ambdaq.figures import pyplot
    from ambdaq.figures.signal import draw_signal

    fig = draw_signal(load(spindle_file), "/amb/rotor", "speed", None)
    try:
        ax = fig.axes[0]
        assert ax.get_ylabel() == "speed [rpm]"
        ys = np.concatenate([line.get_ydata() for line in ax.get_lines()])
        assert np.allclose(ys, 30000.0, rtol=1e-6), (ys.min(), ys.max())
    finally:
        pyplot().close(fig)

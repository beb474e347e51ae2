"""The validation campaign (campaign.py) in the default suite, small: a few seeds of each estimator
at the operating points the docs send users to, against the simulator's truth; it fails when an
estimator drifts. The whole campaign, with more seeds and points, runs under ``-m validation``
and regenerates docs/validation.md (``python tests/validation/campaign.py``)."""

import pytest

import campaign
from ambdaq.speed import SLOW_ROLL_RPM

pytestmark = pytest.mark.offline  # no device, no wall clock: the third worker may run it (tests/scheduling.py)


def test_runout_on_a_slow_roll_is_the_truth_within_its_uncertainty():
    """Eight 1 s slow rolls without unbalance (so the 1X is the runout alone), 1X-6X: the
    estimates' scatter about the true runout is the stated uncertainty, pooled over the 30 axes
    and orders (480 values: the ratio known to about 3 %, so issue 39's 0.9-1.1 holds it); a single
    axis and order's ratio from 16 values is only known to 18 %, and is checked with 30 runs in the
    whole campaign (-m validation). No bias beyond 4 standard errors of the mean."""
    row = campaign.runout(1.0, SLOW_ROLL_RPM, range(1, 9), unbalance=False)
    assert 0.9 <= row.figures["pooled"] <= 1.1, row
    assert row.figures["bias_z"] < 4.0, row


def test_runout_of_chosen_harmonics_fits_every_order_below_them():
    """2X-6X asked of a 1 s slow roll (13.3 revolutions): the 1X, 18 um, is fitted too and not
    reported; left out of the fit it had leaked 306 nm (74 standard errors) into the others."""
    row = campaign.runout(1.0, SLOW_ROLL_RPM, range(1, 6), harmonics=(2, 3, 4, 5, 6))
    assert row.figures["bias_z"] < 4.0 and 0.85 <= row.figures["pooled"] <= 1.15, row


def test_runout_at_speed_is_within_its_uncertainty_and_the_current_model_bound():
    """2X-4X at 30,000 rpm (1X holds the unbalance response, which identify says): the scatter
    about the mean is the stated uncertainty, and the bias from the truth is within the stated
    model bound identify states (``bound_um``: campaign.runout's ``within_bound``)."""
    row = campaign.runout(0.3, 30000.0, range(1, 9), harmonics=(2, 3, 4), skip_s=0.05)
    assert 0.85 <= row.figures["pooled_about_mean"] <= 1.15, row
    assert row.figures["within_bound"], row


def test_the_centreline_is_the_rotors_mean_position():
    row = campaign.centreline(2.0, 20000.0, range(1, 2))
    assert row.holds, row


def test_the_stability_peak_is_the_linearised_loops():
    row = campaign.stability(12000.0, ("front_x",), range(1, 3))
    assert row.holds, row


@pytest.mark.parametrize("make", campaign.SMALL[5:], ids=["critical-speed", "apht", "iso-14839-2", "self-sensing",
                                                          "modal", "drop", "mfxlms", "fir"])
def test_a_small_row_of_every_other_estimator_holds(make):
    """One seed of each other estimator's row (campaign.SMALL): what it states, against the
    simulators' truth; the whole campaign has the seeds and the operating points."""
    row = make()
    assert row.holds, campaign.table([row])


@pytest.mark.validation
def test_the_whole_campaign_holds(tmp_path):
    """Every row of the full campaign (a minute or two here): what docs/validation.md reports."""
    rows = [make() for make in campaign.FULL]
    assert all(r.holds for r in rows), campaign.table([r for r in rows if not r.holds])


def test_the_runups_1x_is_the_true_rotors():
    row = campaign.one_x(3.0, 30000.0, range(1, 2))
    assert row.holds, row

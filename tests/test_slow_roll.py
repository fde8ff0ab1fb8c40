"""Slow-roll compensation on closed-form swept records: a known runout (1X, 2X per channel) under a known dynamic
response, recovered and removed within a few sigma; dynamics in the band flagged per probe; a record too short."""

import warnings

import numpy as np
import pandas as pd
import pytest
from swept_signals import Response, Sweep, swept_record

from hybridtwin.data.order_tracking import TrackingError, order_vector, track_orders
from hybridtwin.data.slow_roll import RUNOUT_COLUMNS, SlowRollWarning, runout, slow_roll_band, slow_roll_compensation

SWEEP = Sweep(r0=100.0, r1=1000.0, bow=30.0)


def truth(record, channel, h):
    i = "xy".index(channel)
    return (record.response.runout_1x_m if h == 1 else record.response.runout_2x_m)[i]


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_runout_recovered_and_removed(seed):
    """Critical speed 3000 RPM, beyond the sweep: at the band's top (~200 RPM) the 1X response is 20 um x
    (200/3000)^2 = 0.09 um, its r^4 remainder 4e-4 um, far below the runout's sigma (~0.1 um): the intercept a is
    unbiased, |z| < 5 (Gaussian: 6e-7 per value)."""
    record = swept_record(SWEEP, Response(critical_rpm=3000.0), seed=seed)
    table = track_orders(record)
    with warnings.catch_warnings():
        warnings.simplefilter("error", SlowRollWarning)  # no flag: the band holds runout only
        compensated, found = slow_roll_compensation(table)
    assert list(found.columns) == RUNOUT_COLUMNS and len(found) == 4 and not found["flagged"].any()
    for row in found.itertuples():
        z = (complex(row.runout_re_m, row.runout_im_m) - truth(record, row.channel, row.harmonic)) / row.runout_sigma_m
        assert abs(z.real) < 5 and abs(z.imag) < 5
        assert row.band_rpm_high <= table["rpm"].min() + 0.1 * np.ptp(table["rpm"]) and row.n_windows >= 3
    for i, channel in enumerate("xy"):
        keep = ~compensated[f"unresolved_{channel}"].to_numpy()
        U, sigma = order_vector(compensated, channel, 1)
        z = (U - record.response.dynamic_1x(compensated["rpm"])[i]) / sigma  # the dynamic response alone is left
        assert np.abs(z.real[keep]).max() < 5 and np.abs(z.imag[keep]).max() < 5
        U2, sigma2 = order_vector(compensated, channel, 2)
        assert np.abs((U2 / sigma2)[keep].real).max() < 5  # the 2X was runout only: nothing left
        assert np.all(sigma > order_vector(table, channel, 1)[1])  # the runout's error added
        assert np.allclose(compensated[f"{channel}1_amp_m"], np.abs(U))


def test_dynamics_in_the_band_are_flagged_naming_the_probe():
    """Critical speed 900 RPM: at the band's top the 1X response is ~0.9 um, ~25 % of the runout and well above
    its sigma: flagged for both probes' 1X (their 2X hold runout only), yet the Omega -> 0 intercept still finds
    the runout (the r^4 remainder, 0.04 um, is below its sigma)."""
    record = swept_record(SWEEP, Response(critical_rpm=900.0), seed=1)
    with pytest.warns(SlowRollWarning) as caught:
        found = runout(track_orders(record))
    flagged = found[found["flagged"]]
    assert set(zip(flagged["channel"], flagged["harmonic"])) == {("x", 1), ("y", 1)}
    messages = [str(w.message) for w in caught]
    assert any("swept.csv: probe x, 1X: the slow-roll band" in m and "dynamic response" in m for m in messages)
    for row in found.itertuples():
        z = (complex(row.runout_re_m, row.runout_im_m) - truth(record, row.channel, row.harmonic)) / row.runout_sigma_m
        assert abs(z.real) < 5 and abs(z.imag) < 5


def test_switched_off_leaves_the_table():
    table = track_orders(swept_record(SWEEP, Response(critical_rpm=3000.0), seed=1))
    same, found = slow_roll_compensation(table, enabled=False)
    assert same is table and found.empty and list(found.columns) == RUNOUT_COLUMNS


def test_band_configurable_and_too_short_records_refused():
    table = track_orders(swept_record(SWEEP, Response(critical_rpm=3000.0), seed=1))
    rows = slow_roll_band(table, (150.0, 260.0))
    assert np.all((table["rpm"].iloc[rows] >= 150) & (table["rpm"].iloc[rows] <= 260)) and rows.size >= 3
    with pytest.raises(TrackingError, match=r"swept.csv: 0 window\(s\) in the slow-roll band \[2000, 3000\] RPM"):
        runout(table, (2000.0, 3000.0))
    short = track_orders(swept_record(Sweep(r0=300.0, r1=330.0, duration_s=2.0, bow=0.0), seed=1))  # ~10 turns
    assert len(short) == 1
    with pytest.raises(TrackingError, match="swept.csv: 1 window.*too short for the slow-roll compensation"):
        slow_roll_compensation(short)
    assert isinstance(table, pd.DataFrame)


def test_the_records_own_mode_keeps_the_dynamics_out_of_the_runout():
    """A strong response in the slow-roll band (critical 650 RPM, A = 400 um: ~35 um at the band's top, 200 RPM):
    the Omega^2-only intercept takes the response's r^4 remainder (A r_lo^2 r_hi^2 ~ 0.9 um, many of its sigmas of
    ~0.1 um) as runout; with the record's own mode (``transient.record_mode``: omega_n, zeta fitted to the record's
    1X) as the dynamic shape the runout is recovered within 5 of its sigmas (Gaussian: 6e-7 per value)."""
    from hybridtwin.data.transient import record_mode

    record = swept_record(SWEEP, Response(critical_rpm=650.0, amplitude_m=400e-6), seed=4)
    table = track_orders(record)
    mode = record_mode(table, ["x", "y"])
    assert mode is not None and abs(mode[0] * 30 / np.pi / 650.0 - 1) < 0.01  # the closed form's critical speed
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SlowRollWarning)  # the band holds dynamics: flagged, as it should be
        plain, shaped = runout(table), runout(table, mode=mode)
    worst_plain = 0.0
    for row_plain, row in zip(plain.itertuples(), shaped.itertuples()):
        want = truth(record, row.channel, row.harmonic)
        z = (complex(row.runout_re_m, row.runout_im_m) - want) / row.runout_sigma_m
        assert abs(z.real) < 5 and abs(z.imag) < 5, (row.channel, row.harmonic, z)
        zp = (complex(row_plain.runout_re_m, row_plain.runout_im_m) - want) / row_plain.runout_sigma_m
        worst_plain = max(worst_plain, abs(zp.real), abs(zp.imag))
    assert worst_plain > 5  # the Omega^2 shape alone is biased here: the test can tell the two apart

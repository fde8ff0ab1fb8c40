"""Order tracking against closed-form swept records (tests/swept_signals.py): the speed profile, the order vectors
and their sigmas, the keyphasor's faults refused with the right message, the table on disk."""

import numpy as np
import pandas as pd
import pytest
from swept_signals import Response, Sweep, swept_record

from hybridtwin.data.order_tracking import (
    TrackingError, order_columns, order_vector, read_orders, speed_profile, table_channels, track_orders,
    write_orders,
)
from hybridtwin.data.preprocessing import harmonic_column

FS = 5000.0
DT = 1 / FS


@pytest.fixture(scope="module")
def record():
    return swept_record(seed=3)


@pytest.fixture(scope="module")
def table(record):
    return track_orders(record)


def true_turns(record, profile):
    k = np.arange(profile.marks_s.size) + np.ceil(record.sweep.theta(record.time_s[0]) / (2 * np.pi))
    return record.sweep.time_of_turn(k)


def test_marks_are_the_turns_to_half_a_sample(record):
    profile = speed_profile(record)
    error = profile.marks_s - true_turns(record, profile)
    # each mark is the sample nearest the turn (the sample where the mark passes): within dt/2
    assert np.abs(error).max() <= 0.5 * DT * (1 + 1e-6)
    # unbiased: the mean of K errors uniform in +-dt/2 has sigma dt / sqrt(12 K); 5 of those
    assert abs(error.mean()) < 5 * DT / np.sqrt(12 * error.size)
    assert profile.direction == "runup" and profile.n_revolutions > 600


def test_theta_and_speed_follow_the_closed_form(record):
    profile = speed_profile(record)
    t = record.time_s[(record.time_s > profile.marks_s[0]) & (record.time_s < profile.marks_s[-1])]
    offset = 2 * np.pi * np.ceil(record.sweep.theta(record.time_s[0]) / (2 * np.pi))  # theta = 0 at the first mark
    error = profile.theta(t) - (record.sweep.theta(t) - offset)
    # knots off by at most Omega dt / 2, PCHIP between them adds no overshoot: |error| <= Omega_max dt
    assert np.abs(error).max() <= 2 * np.pi * 1000 / 60 * DT
    # per revolution: the true mean speed over the true turn, within the marks' timing (2 x dt/2 over a period)
    turns = true_turns(record, profile)
    true_rpm = 60.0 / np.diff(turns)
    assert np.all(np.abs(profile.rpm / true_rpm - 1) <= DT / np.diff(turns) * 1.001)


def test_columns_are_the_steady_tables(table):
    assert list(table.columns) == order_columns(["x", "y"], 5)
    for h in (1, 5):
        for part in ("re", "im", "amp", "sigma"):
            assert harmonic_column("x", h, part) in table and harmonic_column("y", h, part) in table
    assert harmonic_column("x1", 2, "re") in order_columns(["x1"], 2)  # x1_2_re_m, as the steady table names it
    assert table_channels(table) == ["x", "y"]
    assert (table["n_rev"] == 6).all() and (table["t_end_s"].to_numpy()[:-1] == table["t_start_s"].to_numpy()[1:]).all()
    rpm = table["rpm"].to_numpy()
    assert np.all(np.diff(rpm) > 0) and np.all(table["rpm_start"] < rpm) and np.all(rpm < table["rpm_end"])


def test_vectors_within_a_few_sigma_of_the_truth(record, table):
    """Every unflagged window's 1X..3X against the closed form at its mean speed: |z| < 5 (for Gaussian errors a
    chance of 6e-7 per value, ~1e-3 over the ~1250 values judged); the flag leaves out windows where the 1X
    changes within the window (the resonance: its bias is what the flag reports)."""
    judged = 0
    for i, channel in enumerate(("x", "y")):
        keep = ~table[f"unresolved_{channel}"].to_numpy()
        assert keep.mean() > 0.8
        for h in (1, 2, 3):
            U, sigma = order_vector(table, channel, h)
            z = (U - record.response.vector(table["rpm"], h)[i]) / sigma
            assert np.abs(z.real[keep]).max() < 5 and np.abs(z.imag[keep]).max() < 5
            judged += 2 * keep.sum()
        # the residual's sd is the noise's (5 um): a sample sd of n values errs by 1/sqrt(2n); 5 of those. Away from
        # the resonance (650 +- 150 RPM, three half-power bandwidths): on its flanks the 1X's change within a window
        # leaves up to ~10 % more in the residual, short of the flag (its sigma is then conservative)
        away = keep & (np.abs(table["rpm"].to_numpy() - 650.0) > 150.0)
        noise, n = table[f"noise_{channel}_m"].to_numpy()[away], table["n_samples"].to_numpy()[away]
        assert np.all(np.abs(noise / record.noise_m - 1) < 5 / np.sqrt(2 * n))
    assert judged > 1000


def test_sigmas_match_the_scatter_over_seeds():
    """The pooled variance of each window's estimate over 6 seeds (noise and keyphasor quantisation drawn anew:
    a random sub-sample time shift), about its own mean, against the mean predicted sigma^2. With ~100 windows x
    2 parts x 5 degrees of freedom the ratio's standard error is sqrt(2 / 1000) = 0.045; tolerance 5 of those."""
    estimates, sigmas, flagged = [], [], []
    for seed in range(6):
        table = track_orders(swept_record(seed=100 + seed))
        estimates.append([order_vector(table, "x", h)[0] for h in (1, 2)])
        sigmas.append([order_vector(table, "x", h)[1] for h in (1, 2)])
        flagged.append(table["unresolved_x"].to_numpy())
    n = min(len(f) for f in flagged)
    keep = ~np.any([f[:n] for f in flagged], axis=0)
    for h in range(2):
        U = np.array([e[h][:n] for e in estimates])[:, keep]
        s = np.array([g[h][:n] for g in sigmas])[:, keep]
        scatter = (U.real.var(0, ddof=1) + U.imag.var(0, ddof=1)).sum() / 2
        predicted = (s**2).mean(0).sum()
        assert scatter / predicted == pytest.approx(1.0, abs=5 * np.sqrt(2 / (2 * 5 * keep.sum())))


def test_a_line_that_is_no_order_is_flagged(record):
    hum = swept_record(seed=3)
    hum.channels["x"] = hum.channels["x"] + 10e-6 * np.sin(2 * np.pi * 50.0 * hum.time_s)  # 50 Hz mains hum
    table = track_orders(hum)
    assert table["unresolved_x"].mean() > 0.9  # 10 um of hum against 5 um noise: the ratio ~ 2 everywhere
    quiet = track_orders(swept_record(Sweep(), Response(amplitude_m=0.0), seed=4))
    assert not quiet["unresolved_x"].any() and not quiet["unresolved_y"].any()  # no false flag on noise alone


def test_keyphasor_levels_give_the_same_marks(record):
    levels = swept_record(seed=3)
    levels.keyphasor = np.where(record.keyphasor, 5.0, 0.0)  # one-sample 0/5 V pulses
    assert np.array_equal(speed_profile(levels).marks_s, speed_profile(record).marks_s)


def test_missed_mark_is_refused_naming_file_and_line(record):
    bad = swept_record(seed=3)
    index = np.flatnonzero(bad.keyphasor)[100]
    bad.keyphasor = bad.keyphasor.copy()
    bad.keyphasor[index] = False
    with pytest.raises(TrackingError) as err:
        speed_profile(bad)
    message = str(err.value)
    assert message.startswith("swept.csv: column keyphasor: missed mark(s)") and "2.00x its neighbours" in message
    previous = np.flatnonzero(bad.keyphasor)[99]
    assert f"line {previous + 2}-" in message


def test_double_mark_is_refused(record):
    bad = swept_record(seed=3)
    marks = np.flatnonzero(bad.keyphasor)
    bad.keyphasor = bad.keyphasor.copy()
    bad.keyphasor[(marks[200] + marks[201]) // 2] = True
    with pytest.raises(TrackingError, match=r"swept.csv: column keyphasor: double mark\(s\).*0\.5"):
        speed_profile(bad)


def test_reversing_speed_is_refused():
    # rpm(t) = 300 + 700 t/T - 400 sin(pi t/T): slows from 300 to ~190 RPM, then rises to 1000 RPM
    reversing = swept_record(Sweep(bow=-400.0), seed=1)
    with pytest.raises(TrackingError, match="swept.csv: the speed profile reverses: a runup that slows down"):
        speed_profile(reversing)


def test_runup_called_coastdown_is_refused(record):
    with pytest.raises(TrackingError, match="a coastdown that speeds up overall, from"):
        speed_profile(record, direction="coastdown")


def test_coastdown_is_tracked():
    down = swept_record(Sweep(r0=1000.0, r1=300.0, bow=-60.0), seed=2)
    table = track_orders(down, direction="coastdown")
    assert table.attrs["direction"] == "coastdown" and np.all(np.diff(table["rpm"]) < 0)
    U, sigma = order_vector(table, "y", 1)
    keep = ~table["unresolved_y"].to_numpy()
    z = (U - down.response.vector(table["rpm"], 1)[1]) / sigma
    assert np.abs(z[keep].real).max() < 5 and np.abs(z[keep].imag).max() < 5


def test_no_keyphasor_and_too_short_are_refused(record):
    none = swept_record(seed=3)
    none.keyphasor = None
    with pytest.raises(TrackingError, match="swept.csv: no keyphasor column: a runup or coastdown record needs"):
        speed_profile(none)
    short = swept_record(Sweep(duration_s=0.5, r0=300.0, r1=400.0, bow=0.0), seed=3)  # ~2.9 turns
    with pytest.raises(TrackingError, match="whole revolution.*order tracking needs at least 6"):
        track_orders(short)


def test_table_round_trips_exactly(table, tmp_path):
    write_orders(table, tmp_path / "orders.tsv")
    again = read_orders(tmp_path / "orders.tsv")
    pd.testing.assert_frame_equal(again, table.reset_index(drop=True), check_exact=True)

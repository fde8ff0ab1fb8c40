"""Our fault effects (src/hybridtwin/model/faults.py) against ROSS's own time integration of the same faults
(hybridtwin.peers.ross_faults, hybridtwin.peers.ross_fault_cases; issue 54): ROSS 2.3.0's ``rotor_example_with_damping()`` at 1200 RPM, ROSS's Newmark
integration from rest (dt 1e-4 s) order-tracked over its last 20 turns (a Blackman-Harris window: the start-up's free
modes, 9-10 frequency bins from the orders compared, leak about 1e-5 of themselves), our harmonic balance (5
harmonics) of the same rotor imported with ``machine_from_ross`` and our effect for the same fault.

Tolerances, from what each side leaves out (module docstring of ross_faults):

- misalignment (a prescribed force pair; ours its 2X part): the 2X is the same linear response of the same force.
  Held at 1e-3 of ROSS's largest 2X: Newmark's period error at 2X, (omega dt)^2 / 12 = 5e-5, and the window's
  leakage leave that much room. The 1X differs by ROSS's force's own 1X (asserted present: our effect is its 2X).
- crack (the loss acting on the static sag kept, on the dynamic deflection left out): the difference is of the order
  of the left-out share s = |t . q_dyn| / |t . q_s| at the crack, which our side computes: 1X and 2X within 2 s,
  3X within 4 s (its forcing sums three products of the loss's and the response's harmonics); and it shrinks with
  the share: from depth ratio 0.2 to 0.1 the 2X difference falls with s to within a factor 1.6 (measured 0.281 at
  s = 0.201, 0.062 at s = 0.048: 1.40 and 1.29 times s).
- rub (friction 0 and contact damping 0: the conventions differ there): the same contact spring on both sides. Our
  periodic orbit is unstable there (Floquet radius 1.03, asserted) and ROSS's motion wanders around it: a component
  near 39.5 Hz comes and goes (2-10 um) beside a steady 1X (81-82 um over the last 5 s). The 1X is held at 5 % of
  ROSS's (measured 1.8 %): ROSS's force lags one time step (its Newmark takes the fault's force at the previous
  step's deflection, a negative damping k dt = 110 N s/m in contact) and the wandering part leaks into the 1X.

ROSS's integrations take 1-3 minutes each: this file runs in the CI's ROSS step (.ci/run), skipped without ROSS.
"""

import numpy as np
import pytest
from test_ross import rs  # noqa: F401 (the fixture importing ROSS, or skipping)

from hybridtwin.peers.ross_faults import coupling_force, order_harmonics
from hybridtwin.peers.ross_fault_cases import CASES, run_case


@pytest.fixture(scope="module")
def rotor(rs):  # noqa: F811 (the fixture)
    return rs.rotor_example_with_damping()


def test_order_harmonics_of_a_steady_signal_and_a_decaying_mode():
    """The order tracking on a signal written out: harmonics 0..3 exactly (whole turns, window or not), and a free
    mode at 29.5 Hz decaying from 1 mm (the example rotor's first modes are 28.9 and 29.9 Hz) leaks about 1e-5 of
    itself into the 1X and 2X at 20 and 40 Hz."""
    dt, rpm = 1e-4, 1200.0
    t = np.arange(0.0, 2.0, dt)
    W = rpm * np.pi / 30
    X = np.array([3e-6, 2e-6 - 1e-6j, 5e-7j, -1e-7])
    y = sum((X[h] * np.exp(1j * h * W * t)).real for h in range(4))
    np.testing.assert_allclose(order_harmonics(y[:, None], dt, rpm, 20)[:, 0], X, atol=1e-18)
    mode = 1e-3 * np.exp(-1.1 * t) * np.cos(2 * np.pi * 29.5 * t + 0.3)
    leak = order_harmonics((y + mode)[:, None], dt, rpm, 20)[:, 0] - X
    # the mode's amplitude as the window opens (t = 1 s); measured 1.0e-5 of it: its decay widens its line a little
    assert np.abs(leak[1:3]).max() < 2e-5 * 1e-3 * np.exp(-1.1 * 1.0)


def test_misalignment_2x_is_rosss_to_its_integration_error(rotor):
    result = run_case(rotor, "misalignment_parallel")
    assert result.converged
    assert result.difference(2) < 1e-3
    # ROSS's force has a 1X too (Xia et al.'s coupling; 0.19 N beside the 2X's 11.3 N), which ours leaves out: beside
    # the small unbalance's 1X (1.6 um) it moves ROSS's 1X by 12 % (the 2X's agreement shows the rotors are the same)
    _, parameters, _, _ = CASES["misalignment_parallel"]
    ross_parameters = {k: v for k, v in parameters.items() if k != "n"}
    assert max(map(abs, coupling_force(rotor, parameters["n"], 1, **ross_parameters))) > 0.01 * max(
        map(abs, coupling_force(rotor, parameters["n"], 2, **ross_parameters)))
    assert result.difference(1) > 1e-2


def test_crack_agrees_within_its_left_out_share_and_converges_with_it(rotor):
    shallow, deep = run_case(rotor, "crack_mayes_0.1"), run_case(rotor, "crack_mayes_0.2")
    for result in (shallow, deep):
        assert result.converged
        s = result.share
        assert result.difference(1) < 2 * s and result.difference(2) < 2 * s and result.difference(3) < 4 * s
    assert shallow.share < 0.5 * deep.share  # a shallower crack: less of its response is its own
    ratio = (deep.difference(2) / deep.share) / (shallow.difference(2) / shallow.share)
    assert 1 / 1.6 < ratio < 1.6  # the difference is the left-out term's


def test_rub_agrees_at_rosss_contact_spring(rotor):
    result = run_case(rotor, "rub")
    assert result.converged
    assert np.abs(result.theirs[1]).max() > 7.95e-5  # the orbit reaches the clearance: the rub acts
    assert result.difference(1) < 0.05
    assert result.floquet_radius > 1.0  # our periodic orbit is unstable: ROSS's 2X is not a steady one to compare

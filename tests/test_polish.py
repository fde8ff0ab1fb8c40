"""The full-solver polish never ends worse than its best start, scores every start, and looks across the
box when the library's basin is not the solver's.

A toy pair of forward models stands in for library and solver (closed forms, so the optimum is known):
the "solver" response of one parameter a in [-1, 1] is 1e-3 m (sin 5a, sin 3a) at 1X, whose weighted
chi^2 against data made at a = 0.8 has its global minimum (0) at a = 0.8 and non-zero local minima
elsewhere; the "library" is the solver shifted by 0.85 in a (a surrogate error), so its optimum a = -0.05
lies in a basin of the solver that does not hold the truth.
"""

from __future__ import annotations

import numpy as np

from hybridtwin.identify import identification as idn
from hybridtwin.identify import polish as pol
from hybridtwin.identify.protocol import ProtocolOptions

TRUTH = 0.8
SCALE = 1e-3  # [m]
SIGMA = 1e-6  # [m]: chi^2 of a wrong basin is ~(1e-3 / 1e-6)^2, a misfit nothing can hide
SHIFT = 0.85  # the library optimum a = -0.05 sits at the solver's local minimum a = -0.051 (chi^2 / SCALE^2 = 0.94)


class Toy:
    """M (N, 1, 2) = SCALE (sin 5 (a + shift), sin 3 (a + shift)) and its exact derivative."""

    parameters = ["a"]
    lower, upper = np.array([-1.0]), np.array([1.0])
    H = 1

    def __init__(self, shift: float = 0.0):
        self.shift = shift
        self.n_solves = 0

    def evaluate(self, x, jacobian=True):
        a = np.atleast_2d(x)[:, 0] + self.shift
        self.n_solves += a.size
        M = SCALE * np.stack([np.sin(5 * a), np.sin(3 * a)], axis=-1)[:, None, :] + 0j
        dM = SCALE * np.stack([5 * np.cos(5 * a), 3 * np.cos(3 * a)], axis=-1)[:, None, :, None] + 0j
        return M, (dM if jacobian else None)


def _library_fit():
    X = Toy().evaluate(np.array([[TRUTH]]))[0][0]  # (1, 2): noise-free data at the truth
    # a keyphasor with a tight prior keeps the phase (a nuisance here) at 0
    data = idn.RunData("r", 800.0, 14.8, "fit", X, np.full((1, 2), SIGMA), phase_sigma=1e-9)
    options = ProtocolOptions(trials=5, monte_carlo=0, seed=3)
    return idn.identify([Toy(shift=SHIFT)], [data], (), options)


def test_the_library_optimum_is_in_a_wrong_basin_of_the_solver():
    # the premise of the other tests: the library's optimum is its own, far from the truth
    fit = _library_fit()
    assert abs(fit.x[0] - (TRUTH - SHIFT)) < 1e-3


def test_polish_scores_every_start_and_ends_at_the_best():
    fit = _library_fit()
    starts = np.array([[0.0, 0.0], [-0.9, 0.0]])  # [a, phase]
    polished = pol.polish(fit, [Toy()], starts=starts, labels=["library optimum", "zero", "low edge"],
                          random_starts=0)
    table = polished.starts
    assert list(table["start"]) == ["library optimum", "zero", "low edge"]
    # each start's chi^2 is the solver's at that start: recompute it independently
    for row, theta in zip(table.itertuples(), np.vstack([fit.theta[None], starts])):
        M = Toy().evaluate(theta[None, :1])[0][0]
        chi2 = (np.abs((fit.X[0] - M) / SIGMA) ** 2).sum() * 2 / 2  # |z|^2 = Re^2 + Im^2, both residuals
        assert np.isclose(row.chi2_start, chi2 + (theta[1] / 1e-9) ** 2, rtol=1e-6)
        assert row.chi2 <= row.chi2_start  # LM only accepts steps that lower chi^2
    assert table["selected"].sum() == 1
    assert polished.uncertainty.chi2 <= table["chi2_start"].min() * (1 + 1e-9)  # never worse than a start
    assert np.isclose(polished.uncertainty.chi2, table["chi2"].min(), rtol=1e-9)
    # the selected start's chi^2/dof is the result's (one count of the dof: the data and the phase prior less
    # the free entries), as the log and the ledger print it
    selected = table[table["selected"]].iloc[0]
    assert np.isclose(selected.chi2_dof, polished.uncertainty.chi2_dof, rtol=1e-9)
    assert polished.uncertainty.dof == 4 + 1 - 2  # Re, Im of 1X of two channels and the prior; a and the phase


def test_a_large_misfit_brings_random_starts_that_find_the_solver_basin():
    fit = _library_fit()
    alone = pol.polish(fit, [Toy()], random_starts=0)
    # from the library optimum alone the polish stays in the wrong basin: a misfit far above MISFIT
    assert alone.chi2_dof > 100 * pol.MISFIT
    across = pol.polish(fit, [Toy()], random_starts=6, seed=5)
    assert len(across.starts) == 7 and across.starts["start"].str.startswith("random start").sum() == 6
    # a Latin hypercube of 6 in [-0.9, 0.9] puts one start in each 0.3-wide stratum, so one in [0.6, 0.9],
    # inside the truth's basin (~(0.4, 1]) whatever the seed: chi^2 at the noise-free truth is ~0, a within 1e-6
    assert across.chi2_dof < 1.0
    assert abs(across.x[0] - TRUTH) < 1e-6
    assert across.uncertainty.chi2 <= alone.uncertainty.chi2


def test_no_random_starts_when_the_fit_is_good():
    X = Toy().evaluate(np.array([[TRUTH]]))[0][0]
    data = idn.RunData("r", 800.0, 14.8, "fit", X, np.full((1, 2), SIGMA), phase_sigma=1e-9)
    fit = idn.identify([Toy()], [data], (), ProtocolOptions(trials=5, monte_carlo=0, seed=3))
    polished = pol.polish(fit, [Toy()], random_starts=6)
    assert len(polished.starts) == 1  # the library optimum already explains the data


def test_polish_starts_add_the_parents_refit_with_the_added_effect_only():
    """run_fits.polish_starts after the library optimum: the next-best trials, then the parent variant's diagnosis
    refit with the effect this variant adds (its row of diagnosis_refits.tsv, normalised with this fit's ranges),
    never another effect's refit; a parent that did not refit the effect adds nothing and says so."""
    import pandas as pd

    from hybridtwin.identify.run_fits import polish_starts

    fit = _library_fit()
    refits = pd.DataFrame({"effect": ["other", "speed_damping", "speed_damping"], "parameter": ["a", "a", "phase"],
                           "run": ["all", "all", "r"], "value": [-0.7, 0.5, 0.1]})
    messages = []
    starts, labels = polish_starts(fit, None, ("base", "speed_damping", refits), (), messages)
    trials = pol.next_best_trials(fit)
    np.testing.assert_array_equal(starts[:-1], trials)
    np.testing.assert_allclose(starts[-1], [0.5, 0.1], rtol=0, atol=1e-15)  # a in [-1, 1]: normalised = SI
    assert labels == ["library optimum"] + [f"library trial {i + 2}" for i in range(len(trials))] \
        + ["base's diagnosis refit with speed_damping"]
    assert messages == ["polish also starts from base's diagnosis refit with speed_damping: found"]
    messages = []
    starts, labels = polish_starts(fit, None, ("base", "moment_stiffness", refits), (), messages)
    assert len(starts) == len(trials) and len(labels) == len(trials) + 1
    assert messages == ["polish also starts from base's diagnosis refit with moment_stiffness: not there "
                        "(not refitted)"]

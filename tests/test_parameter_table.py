"""The parameter table (parameters.tsv) read back: ``Identification.from_table`` is the exact inverse of
``Identification.table`` for what the table holds, in memory and through the TSV writer and reader.

Real small fits on the toy model of test_identification (three parameters, two harmonics): a joint fit of
three runs with one parameter per run and Monte Carlo repeats (shared, per-run and nuisance rows, the Monte
Carlo columns filled), and a per-run fit without repeats (kind "physical", Monte Carlo columns NaN).
"""

import numpy as np
import pandas as pd
import pytest

from hybridtwin.identify import identification as idn
from hybridtwin.identify import protocol
from test_identification import ToyModel, toy_data


@pytest.fixture(scope="module")
def fits():
    x_true = np.array([0.3, -0.4, 0.5])
    data = [toy_data(x_true, phase, noise=1.0, seed=seed, run=run)
            for phase, seed, run in ((0.4, 1, "001"), (-1.0, 2, "r2"), (2.5, 3, "10"))]
    options = protocol.ProtocolOptions(trials=6, monte_carlo=12, monte_carlo_starts=2, seed=4)
    units = {"a": "N/m", "b": "1"}  # c has no unit: the table writes ""
    joint = idn.identify([ToyModel()] * 3, data, per_run=["c"], options=options, units=units)
    single = idn.identify([ToyModel()], data[:1], options=protocol.ProtocolOptions(trials=6, monte_carlo=0, seed=5),
                          units=units)
    return {"joint": joint, "single": single}


@pytest.mark.parametrize("name", ["joint", "single"])
def test_from_table_is_the_exact_inverse_of_table(fits, name):
    fit = fits[name]
    table = fit.table()
    back = idn.Identification.from_table(table, parameters=ToyModel.parameters)
    pd.testing.assert_frame_equal(back.table(), table, check_exact=True)
    # what the table holds, as the fit has it (theta of a phase: its wrapped value, as x)
    assert back.layout.runs == fit.layout.runs and back.layout.shared == fit.layout.shared
    assert back.layout.local == fit.layout.local and back.layout.parameters == fit.layout.parameters
    assert back.layout.lower == fit.layout.lower and back.layout.upper == fit.layout.upper
    np.testing.assert_array_equal(back.x, fit.x)
    physical = ~fit.layout.is_phase
    np.testing.assert_array_equal(back.theta[physical], fit.theta[physical])
    for run in fit.layout.runs:
        assert back.values(run) == fit.values(run)
        assert back.x[back.entry("phase", run)] == fit.x[fit.entry("phase", run)]
    assert back.units == {"a": "N/m", "b": "1", "c": ""} and back.source == "library"


@pytest.mark.parametrize("name", ["joint", "single"])
def test_the_tsv_written_and_read_back_is_the_same_table(fits, name, tmp_path):
    path = tmp_path / "parameters.tsv"
    idn.write_parameters(fits[name].table(), path)
    read = idn.read_parameters(path)
    assert read["run"].tolist()[-1] in ("001", "10")  # run ids stay text ("001", not 1)
    back = idn.Identification.from_table(read, parameters=ToyModel.parameters)
    pd.testing.assert_frame_equal(back.table(), read, check_exact=True)
    again = tmp_path / "again.tsv"
    idn.write_parameters(back.table(), again)
    assert again.read_text() == path.read_text()
    # the written digits: 9 significant, so the values read back are the fit's to ~5e-9 relative
    np.testing.assert_allclose(back.x, fits[name].x, rtol=1e-8, atol=1e-12)


def test_a_result_read_from_a_table_says_what_it_lacks(fits):
    back = idn.Identification.from_table(fits["joint"].table())
    assert back.layout.parameters == ("a", "b", "c")  # default order: shared, then per-run
    with pytest.raises(ValueError, match="read from a parameter table"):
        back.fitted()
    with pytest.raises(ValueError, match="no column"):
        idn.Identification.from_table(fits["joint"].table().drop(columns="stderr"))
    with pytest.raises(ValueError, match="not in the order"):
        idn.Identification.from_table(fits["joint"].table().iloc[::-1])
    with pytest.raises(KeyError, match="no entry"):
        back.entry("c", "not a run")


def test_a_run_left_out_has_a_table_that_reads_back(fits, tmp_path):
    """A run that is not usable is not fitted (run_fits.excluded_table): the same columns, NaN estimates, its
    note; read back, a joint start from it is None and the reader keeps the note out of the estimates."""
    from types import SimpleNamespace

    from hybridtwin.identify.run_fits import excluded_table, start_from_runs

    data = toy_data([0.0, 0.0, 0.0], 0.0, run="007")
    library = SimpleNamespace(parameters=ToyModel.parameters, lower=ToyModel.lower, upper=ToyModel.upper)
    table = excluded_table(data, library.parameters, library.lower, library.upper, {"a": "N/m"}).assign(
        note="record too short")
    path = tmp_path / "parameters.tsv"
    idn.write_parameters(table, path)
    read = idn.read_parameters(path)
    back = idn.Identification.from_table(read)
    pd.testing.assert_frame_equal(back.table(), read.drop(columns="note"), check_exact=True)
    assert np.isnan(back.x).all() and read["note"].eq("record too short").all()
    assert start_from_runs(fits["joint"].layout, {"007": back}) is None


def test_start_from_runs_takes_the_median_and_each_runs_own_entries(fits):
    """Per-run fits read back from their tables: shared entries at the median of the runs' normalised
    estimates, c (per run) and the phase from each run's own fit."""
    from hybridtwin.identify.run_fits import start_from_runs

    joint = fits["joint"]
    runs = {}
    for k, run in enumerate(joint.layout.runs):
        table = fits["single"].table()
        table["run"] = run
        table["normalised"] = table["normalised"] + 0.01 * k  # 3 runs, distinct estimates
        table.loc[table["parameter"] == "phase", "value"] = 0.1 * k
        runs[run] = idn.Identification.from_table(table)
    theta = start_from_runs(joint.layout, runs)
    single = fits["single"].theta
    expected = {("a", "all"): single[0] + 0.01, ("b", "all"): single[1] + 0.01}  # the median of three
    for k, run in enumerate(joint.layout.runs):
        expected |= {("c", run): single[2] + 0.01 * k, ("phase", run): 0.1 * k}
    assert dict(zip(joint.layout.entries(), theta)) == pytest.approx(expected, abs=1e-15)


def test_mc_note_says_when_the_monte_carlo_mean_is_not_the_estimates_spread(fits, tmp_path):
    """parameters.tsv's mc_mean could have the opposite sign of value with no word (issue 39, item 4): mc_note says
    why (``MC_NOTES``). Rows of the bundled run (main job at 6f13abf): a loose per-run k4 and k5 whose repeats
    straddle zero ("sign": the data do not fix the sign), a per-run k6 whose repeats settle at another optimum, the
    estimate outside their interval ("elsewhere"), a polished joint fit's phase and k_b, the library's repeats
    elsewhere ("polished"); a phase is never "sign" (an angle)."""
    rows = pd.DataFrame([  # value, mc_mean, mc_ci_low, mc_ci_high, parameter, source (run: the bundled run's)
        (-268.412615, 111.726614, -538.216153, 822.085184, "k4", "library"),  # geometric_expansion_k4 r900_m0p0
        (560.378105, -101.84783, -1000.0, 673.559694, "k5", "library"),  # expansion r950_m0p0
        (475.189346, -318.696935, -901.873241, 445.447554, "k6", "library"),  # expansion r600_m25p9
        (0.16460848, -1.15328402, -1.16187696, -1.14442699, "phase", "solver"),  # final, joint
        (2980.96106, 2897.00639, 2894.66772, 2899.6051, "k_b", "solver"),  # geometric, joint
        (0.3, -0.1, -0.5, 0.5, "phase", "library"),  # a phase's sign says nothing
        (2411.6, 2411.5, 2410.0, 2413.0, "k_b", "solver"),  # as it should be
        (2411.6, np.nan, np.nan, np.nan, "k_b", "solver"),  # no repeats
    ], columns=["value", "mc_mean", "mc_ci_low", "mc_ci_high", "parameter", "source"])
    notes = idn.mc_notes(rows["value"], rows["mc_mean"], rows["mc_ci_low"], rows["mc_ci_high"],
                         rows["parameter"] == "phase", rows["source"] == "solver")
    assert notes == ["sign", "sign", "elsewhere", "polished", "polished", "", "", ""]
    # the table's column, from its own numbers; the writer and reader keep it exactly
    table = fits["joint"].table()
    assert "mc_note" in idn.TABLE_COLUMNS and set(table["mc_note"]) <= set(idn.MC_NOTES) | {""}
    assert table["mc_note"].tolist() == idn.mc_notes(table["value"], table["mc_mean"], table["mc_ci_low"],
                                                     table["mc_ci_high"], table["parameter"] == "phase", False)
    assert (fits["single"].table()["mc_note"] == "").all()  # no repeats, nothing to say
    table.loc[0, ["mc_mean", "mc_ci_low", "mc_ci_high"]] = [-table.loc[0, "value"], -1e3, 1e3]
    table.loc[0, "mc_note"] = "sign"
    table.loc[1, "mc_note"] = "elsewhere"
    idn.write_parameters(table, tmp_path / "parameters.tsv")
    read = idn.read_parameters(tmp_path / "parameters.tsv")
    pd.testing.assert_frame_equal(idn.Identification.from_table(read, ToyModel.parameters).table(), table,
                                  check_exact=False, rtol=1e-8)
    # a table written before mc_note existed reads with it, from its own numbers
    idn.write_parameters(table.drop(columns="mc_note"), tmp_path / "old.tsv")
    old = idn.read_parameters(tmp_path / "old.tsv")
    assert list(old.columns) == list(idn.TABLE_COLUMNS) and old["mc_note"].tolist()[0] == "sign"

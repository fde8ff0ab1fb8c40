"""The per-run stage (paper sec. 4.1): each fit run identified alone on its library by the paper's protocol.

One run's fit (tau = 50 trials, n_MC = 1000 repeats, ``hybridtwin.protocol``) takes about a second, less
than a workflow job's start-up (Python, numpy, the package: 1-2 s), so the workflow fits every run of a
variant in one job (rule identify_runs), run after run, each written to its own files as before:
results/{variant}/runs/{run}/parameters.tsv, history.tsv and fit.zarr.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from . import forward as fwd
from . import identification as idn
from . import polish as pol
from .library import Library
from .variants import Variant


@dataclass
class RunFit:
    """One run's per-run fit: the parameter table (``Identification.table`` plus a note), the loss history,
    the identification (None for a run that is not usable), and the lines for the log."""

    run: str
    parameters: pd.DataFrame
    history: pd.DataFrame
    fit: idn.Identification | None
    data: idn.RunData
    messages: list[str]
    warnings: list[str]


def fit_run(variant: Variant, options: Mapping, library: Library, data: idn.RunData,
            validation: pd.DataFrame | None, harmonics: int) -> RunFit:
    """``data``'s run alone on its ``library`` by the paper's protocol (``options``: ``identification.settings``),
    polished with the full solver when ``polish: runs`` is set. A run that is not usable is not fitted: its
    table holds NaN and the reason."""
    run, units = data.run, idn.units(variant)
    if not data.usable:
        empty = pd.DataFrame(columns=["trial", "iteration", "loss", "selected"])
        return RunFit(run, excluded_table(data, library.parameters, units), empty, None, data, [],
                      [f"run {run} is not usable ({data.note}): not fitted"])
    errors = idn.model_errors(validation, [run], options["model_error"])
    start = time.perf_counter()
    fit = idn.identify([fwd.SensorSurrogate(library)], [data], (), idn.protocol_options(options), errors,
                       units=units)
    messages = [f"run {run}: {len(fit.protocol.trials.loss)} trials x (1 + {len(fit.protocol.monte_carlo)} Monte "
                f"Carlo repeats), {fit.protocol.n_lm} LM problems in {time.perf_counter() - start:.2f} s; best loss "
                f"{fit.loss:.4g} (chi^2/dof {fit.chi2_dof:.3g}, {fit.message}); {fit.summary()['trials_at_best']} "
                f"of {len(fit.protocol.trials.loss)} trials reached it"]
    if options["polish"]["runs"]:
        solver = [fwd.SolverModel(variant, run, data.rpm, data.eccentric_mass_g, library.parameters, library.lower,
                                  library.upper, harmonics)]
        exact = pol.polish(fit, solver, int(options["polish"]["max_iterations"]))
        messages += [f"polish {row.parameter}: library {row.library_value:.6g}, solver {row.solver_value:.6g} "
                     f"({row.difference_in_stderr:.2g} stderr)" for row in pol.compare_polish(fit, exact).itertuples()]
        fit = exact
    table = fit.table()
    table["note"] = "; ".join(fit.uncertainty.notes) or "ok"
    return RunFit(run, table, fit.history_table(), fit, data, messages,
                  [f"run {run}: {note}" for note in fit.uncertainty.notes])


def write_run_fit(result: RunFit, parameters: str, history: str, fit: str) -> None:
    """A run's three files: parameters.tsv, history.tsv and fit.zarr (``identification.write_fit``; for a run
    that was not fitted, a group naming the reason)."""
    result.parameters.to_csv(parameters, sep="\t", index=False, float_format="%.9g")
    result.history.to_csv(history, sep="\t", index=False, float_format="%.9g")
    if result.fit is not None:
        idn.write_fit(fit, result.fit, [result.data.rpm])
        return
    import zarr

    from .stores import write_manifest

    zarr.open_group(fit, mode="w").attrs.update({"runs": [result.run], "note": result.data.note})
    write_manifest(fit)  # its checksums, as every store's (hybridtwin.stores)


def excluded_table(data: idn.RunData, parameters: Sequence[str], units: Mapping[str, str]) -> pd.DataFrame:
    """The parameter table of a run that cannot be fitted (not usable): NaN values and the reason."""
    rows = [{"parameter": p, "run": data.run, "kind": "shared", "unit": units.get(p, ""), "value": np.nan,
             "normalised": np.nan, "stderr": np.nan, "ci_low": np.nan, "ci_high": np.nan, "at_bound": False,
             "identifiable": False, "note": data.note} for p in list(parameters) + ["phase"]]
    rows[-1].update(kind="nuisance", unit="rad")
    return pd.DataFrame(rows)

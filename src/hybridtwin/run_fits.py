"""The per-run stage (paper sec. 4.1): each fit run identified alone on its library by the paper's protocol.

One run's fit (tau = 50 trials, n_MC = 1000 repeats, ``hybridtwin.protocol``) takes about a second, less
than a workflow job's start-up (Python, numpy, the package: 1-2 s), so the workflow fits every run of a
variant in one job (rule identify_runs), run after run, each written to its own files as before:
results/{variant}/runs/{run}/parameters.tsv, history.tsv and fit.zarr.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
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
        return RunFit(run, excluded_table(data, library, units), empty, None, data, [],
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
    idn.write_parameters(result.parameters, parameters)
    result.history.to_csv(history, sep="\t", index=False, float_format="%.9g")
    if result.fit is not None:
        idn.write_fit(fit, result.fit, [result.data.rpm])
        return
    import zarr

    from .stores import write_manifest

    zarr.open_group(fit, mode="w").attrs.update({"runs": [result.run], "note": result.data.note})
    write_manifest(fit)  # its checksums, as every store's (hybridtwin.stores)


def excluded_table(data: idn.RunData, library: Library, units: Mapping[str, str]) -> pd.DataFrame:
    """The parameter table of a run that cannot be fitted (not usable): ``Identification.table``'s rows and
    columns with NaN estimates, and the reason as its note."""
    rows = [{"parameter": p, "run": data.run, "kind": "physical", "unit": units.get(p, ""), "value": np.nan,
             "lower": float(lo), "upper": float(hi)} for p, lo, hi in zip(library.parameters, library.lower,
                                                                          library.upper)]
    rows.append({"parameter": "phase", "run": data.run, "kind": "nuisance", "unit": "rad", "value": np.nan,
                 "lower": -np.pi, "upper": np.pi})
    table = pd.DataFrame(rows).reindex(columns=list(idn.TABLE_COLUMNS))
    table[["at_bound", "identifiable"]] = False
    table["source"], table["note"] = "library", data.note
    return table


def start_from_runs(layout: idn.Layout, per_run: Mapping[str, idn.Identification]) -> np.ndarray | None:
    """A joint start from the per-run fits (read back with ``Identification.from_table``): shared entries at
    the median of the runs' estimates, local ones and phases from each run's own fit (None when a run has no
    usable fit)."""
    theta = np.zeros(layout.n)
    for i, (p, run) in enumerate(layout.entries()):
        if run == "all":
            values = [v for v in (fit.theta[fit.entry(p)] for fit in per_run.values()) if np.isfinite(v)]
            if not values:
                return None
            theta[i] = float(np.median(values))
        elif run in per_run:
            theta[i] = per_run[run].theta[per_run[run].entry(p, run)]
        else:
            return None
    return theta if np.isfinite(theta).all() else None

"""The identification stage's two fits (paper sec. 4.1), what the workflow's rules identify_run and
identify_joint run, and their files.

Per run: each fit run identified alone on its library by the paper's protocol. One run's fit (tau = 50
trials, n_MC = 1000 repeats, ``hybridtwin.identify.protocol``) takes about a second, less than a workflow job's
start-up (Python, numpy, the package: 1-2 s), so the workflow fits every run of a variant in one job, run
after run, each written to its own files: results/{variant}/runs/{run}/parameters.tsv, history.tsv, fit.zarr.

Joint: all fit runs at once, shared physical parameters and per-run ones (``fit_joint``): the library
protocol from random trials and a start from the per-run fits, then, when asked, the full solver's polish
from the library optimum, the next-best trials, the parent variant's diagnosis refit and the joint fits of
the simpler variants nested in this one.

Without libraries (``offline.scope: none``) both fits run on the full harmonic-balance solver
(``forward.SolverModel``: warm starts, analytic sensitivities) from SOLVER_TRIALS random starts, with no Monte
Carlo repeats (the interval from the solver's Jacobian), and the joint fit's polish rule (more random starts where
the misfit stays large) on top. Measured on the run-up example: the offline library stages cost 380 s of CPU out of
the run's 755, while the full solver alone reached the same optimum from 4 random starts in 8 s
(benchmarks/README.md, "Fits on the full solver").

``options`` are the rule's (``hybridtwin.settings.IdentificationSettings.rule``): a job reads nothing else of the
config.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
import zarr

from .. import tables
from . import forward as fwd
from .arrow_problem import Layout
from . import identification as idn
from . import polish as pol
from . import profile as prf
from .protocol import ProtocolOptions
from ..offline.library import Library
from ..offline.stores import write_manifest  # the store's checksums, last: readers verify them
from ..model.effects import trial_angle_rad
from ..model.variants import Variant, embed

Array = np.ndarray

#: a simpler variant's joint fit is a polish start when this variant reproduces it to this coefficient
#: mismatch (``variants.embed``; round-off: ~1e-16)
NESTED_MISMATCH = 1e-6
#: random starts of a fit on the full solver (no libraries, ``offline.scope: none``; module docstring)
SOLVER_TRIALS = 4


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


def ranges(variant: Variant) -> tuple[list[str], Array, Array]:
    """The variant's unknowns and their ranges [SI] in its order (a library's order too)."""
    names = list(variant.unknown)
    lower, upper = (np.array(v, float) for v in zip(*variant.unknown.values()))
    return names, lower, upper


def solver_models(variant: Variant, data: Sequence[idn.RunData], harmonics: int) -> list[fwd.SolverModel]:
    """The full solver as the forward model of each run of ``data`` over the variant's unknowns."""
    names, lower, upper = ranges(variant)
    return [fwd.SolverModel.for_data(variant, d, names, lower, upper, harmonics) for d in data]


def solver_protocol(options: Mapping, joint: bool = False) -> ProtocolOptions:
    """The protocol of a fit on the full solver: SOLVER_TRIALS random starts (or fewer when asked), no Monte Carlo
    repeats (module docstring)."""
    base = idn.protocol_options(options, joint)
    return replace(base, trials=min(base.trials, SOLVER_TRIALS), monte_carlo=0, monte_carlo_starts=0)


def swept_on_library(data) -> str:
    """The warning for a band of a record fitted with the swept model (``RunData.sweep_rpm_s``) whose model is a
    library: a library is the steady state, the correction for the sweep rate is the full solver's
    (``forward.SolverModel``), so near a resonance the band is compared with a model it was not checked against."""
    return (f"run {data.run}: a band swept at {data.sweep_rpm_s:.3g} RPM/s fitted with its library, which holds the "
            "steady state only (the sweep-rate correction is the full solver's): give the record sweep_model "
            "quasi_steady, or fit on the full solver (offline: scope none)")


def refuse_angle_on_library(data: idn.RunData) -> None:
    """The sPGD libraries (offline.scope run or global) are built per (rpm, eccentric mass) with the mass on +x: a
    run whose trial mass is at another angle is refused there, never fitted as if it were on +x."""
    if trial_angle_rad(data.eccentric_mass_angle_deg) != 0.0:
        raise ValueError(f"run {data.run}: its trial mass is at eccentric_mass_angle_deg "
                         f"{data.eccentric_mass_angle_deg:g}, but the sPGD libraries are built per (rpm, eccentric "
                         "mass) with the mass on +x; fit this variant on the full solver (offline: scope: none)")


def fit_run(variant: Variant, options: Mapping, library: Library | None, data: idn.RunData,
            validation: pd.DataFrame | None, harmonics: int) -> RunFit:
    """``data``'s run alone on its ``library`` by the paper's protocol (``options``: ``IdentificationSettings.rule``
    for rule "run"), polished with the full solver when ``options["polish"]`` (its iterations; False: no polish);
    without a library (None: ``offline.scope: none``) on the full solver itself (``solver_protocol``).
    A run that is not usable is not fitted: its table holds NaN and the reason."""
    run, units = data.run, idn.units(variant)
    names, lower, upper = (library.parameters, library.lower, library.upper) if library else ranges(variant)
    if not data.usable:
        empty = pd.DataFrame(columns=tables.HISTORY.columns)
        return RunFit(run, excluded_table(data, names, lower, upper, units), empty, None, data, [],
                      [f"run {run} is not usable ({data.note}): not fitted"])
    errors = idn.model_errors(validation, [run], options["model_error"])
    start = time.perf_counter()
    if library is None:
        fit = idn.identify(solver_models(variant, [data], harmonics), [data], (), solver_protocol(options),
                           units=units)
        messages = [f"run {run}: on the full solver, {len(fit.protocol.trials.loss)} trials in "
                    f"{time.perf_counter() - start:.2f} s; chi^2/dof {fit.chi2_dof:.3g} ({fit.message})"]
    else:
        refuse_angle_on_library(data)
        fit = idn.identify([fwd.SensorSurrogate(library)], [data], (), idn.protocol_options(options), errors,
                           units=units)
        messages = [f"run {run}: {len(fit.protocol.trials.loss)} trials x (1 + {len(fit.protocol.monte_carlo)} "
                    f"Monte Carlo repeats), {fit.protocol.n_lm} LM problems in {time.perf_counter() - start:.2f} s; "
                    f"best loss {fit.loss:.4g} (chi^2/dof {fit.chi2_dof:.3g}, {fit.message}); "
                    f"{fit.summary()['trials_at_best']} of {len(fit.protocol.trials.loss)} trials reached it"]
        messages += [swept_on_library(data)] if data.sweep_rpm_s else []
    if library is not None and options["polish"]:
        solver = [fwd.SolverModel.for_data(variant, data, library.parameters, library.lower, library.upper, harmonics)]
        exact = pol.polish(fit, solver, int(options["polish"]))
        messages += [f"polish {row.parameter}: library {row.library_value:.6g}, solver {row.solver_value:.6g} "
                     f"({row.difference_in_stderr:.2g} stderr)" for row in pol.compare_polish(fit, exact).itertuples()]
        fit = exact
    table = fit.table()
    table["note"] = "; ".join(fit.uncertainty.notes) or "ok"
    return RunFit(run, table, fit.history_table(), fit, data, messages,
                  [f"run {run}: {note}" for note in fit.uncertainty.notes])


def write_run_fit(result: RunFit, parameters: str, history: str, fit: str) -> None:
    """A run's three files: parameters.tsv, history.tsv and fit.zarr (``write_fit``; for a run
    that was not fitted, a group naming the reason)."""
    idn.write_parameters(result.parameters, parameters)
    tables.HISTORY.write(result.history, history)
    if result.fit is not None:
        write_fit(fit, result.fit, [result.data.rpm])
        return
    zarr.open_group(fit, mode="w").attrs.update({"runs": [result.run], "note": result.data.note})
    write_manifest(fit)  # its checksums, as every store's (hybridtwin.offline.stores)


@dataclass
class JointFit:
    """The joint fit of a variant: ``fit`` the final one (the full solver's polish when asked and it solved,
    else the library's), ``library_fit`` the library protocol's, ``comparison`` library vs solver per entry
    (polish.tsv; empty without a polish), ``summary`` (summary.yaml: library, solver, the intervals' profile when a
    parameter is loose, final), the runs fitted,
    and the lines for the log."""

    fit: idn.Identification
    library_fit: idn.Identification
    comparison: pd.DataFrame
    summary: dict
    data: list[idn.RunData]
    messages: list[str]
    warnings: list[str]

    def profile_table(self) -> pd.DataFrame:
        """The fits of the intervals' profile (identification/profile.tsv; empty when no parameter is loose)."""
        return prf.profile_table(self.fit.profile)

    def starts_table(self) -> pd.DataFrame:
        """The polish's starts and where each ended (polish_starts.tsv; empty without a polish)."""
        return self.fit.starts if self.fit.starts is not None else pd.DataFrame(columns=tables.POLISH_STARTS.columns)

    def runs(self) -> pd.DataFrame:
        """The runs fitted: run, rpm, eccentric_mass_g."""
        return pd.DataFrame({"run": [d.run for d in self.data], "rpm": [d.rpm for d in self.data],
                             "eccentric_mass_g": [d.eccentric_mass_g for d in self.data]})


def fit_joint(variant: Variant, options: Mapping, libraries: Sequence[Library], harmonics_table: pd.DataFrame,
              per_run: Mapping[str, pd.DataFrame], validation: pd.DataFrame | None, harmonics: int,
              parent_refit: tuple[str, str, pd.DataFrame] | None = None,
              nested: Sequence[tuple[Variant, pd.DataFrame]] = (), runs: Sequence[str] = ()) -> JointFit:
    """All usable fit runs of ``variant`` at once (``options``: ``IdentificationSettings.rule`` for rule
    "joint"): the parameters in ``options["per_run"]`` per run, the others shared.

    The library protocol (``options["joint"]``'s trials and repeats) adds one start to its random trials: the
    per-run fits (``per_run``: each run's parameter table; ``start_from_runs``). With ``options["polish"]``
    (its iterations; False: none) the full solver (``harmonics`` harmonics) polishes the library optimum from
    these starts (``polish_starts``): the optimum, the next-best trials, ``parent_refit`` (the variant this
    one extends by one effect, that effect, and the parent's diagnosis_refits.tsv: its refit with the effect
    is already a full-solver fit of this model) and the joint fit of each ``nested`` variant (a simpler
    variant this one contains, with its parameters.tsv) mapped onto this variant's parameters. When the
    solver has no periodic solution at any start, the library's estimate is kept, with a note. With
    ``options["profile"]`` (default on), when a shared parameter of the final fit is loose (at a range edge or not
    identifiable), the shared parameters' intervals are profiled over it (``profile.profile_intervals``).
    """
    messages: list[str] = []
    warnings: list[str] = []
    data, models = [], []
    on_solver = not libraries  # offline.scope: none: the fits on the full solver (module docstring)
    for library, name in [(lib, lib.run) for lib in libraries] or [(None, r) for r in runs]:
        run = idn.run_data(harmonics_table, name, keyphasor=options["keyphasor"], channels=variant.channels)
        if not run.usable:
            warnings.append(f"run {run.run} left out of the joint fit: {run.note}")
            continue
        data.append(run)
        if library is not None:
            refuse_angle_on_library(run)
            models.append(fwd.SensorSurrogate(library))
            warnings += [swept_on_library(run)] if run.sweep_rpm_s else []
    if not data:
        raise ValueError(f"variant {variant.name}: no usable fit run for the joint identification")
    if on_solver:
        models = solver_models(variant, data, harmonics)
    errors = idn.model_errors(validation, [d.run for d in data], options["model_error"])
    parameters, lower, upper = models[0].parameters, models[0].lower, models[0].upper
    layout = Layout.for_data(parameters, lower, upper, data, options["per_run"])
    start_theta = start_from_runs(layout, {d.run: idn.Identification.from_table(per_run[d.run]) for d in data
                                           if d.run in per_run})
    start = time.perf_counter()
    protocol = solver_protocol(options, joint=True) if on_solver else idn.protocol_options(options, joint=True)
    fit = idn.identify(models, data, options["per_run"], protocol, errors, extra_starts=start_theta,
                       units=idn.units(variant))
    messages.append(f"joint fit of {len(data)} runs ({layout.n} unknowns) on the "
                    f"{'full solver' if on_solver else 'libraries'}: {fit.protocol.n_lm} LM problems in "
                    f"{time.perf_counter() - start:.1f} s, loss {fit.loss:.4g}, chi^2/dof {fit.chi2_dof:.3g} "
                    f"({fit.message})")
    library_fit, summary = fit, {"library": fit.summary()}
    comparison = pd.DataFrame(columns=tables.POLISH.columns)
    if options["polish"]:
        solver = models if on_solver else solver_models(variant, data, harmonics)
        start = time.perf_counter()
        starts, labels = polish_starts(fit, variant, parent_refit, nested, messages)
        exact = pol.polish(fit, solver, int(options["polish"]), starts, labels, seed=int(options["seed"]))
        if np.isfinite(exact.loss):
            comparison = pol.compare_polish(fit, exact)
            exact.protocol.monte_carlo = fit.protocol.monte_carlo  # the library's Monte Carlo spread, for reference
            best = exact.starts["start"][exact.protocol.best]
            summary["solver"] = exact.summary() | {"seconds": time.perf_counter() - start,
                                                   "solves": int(sum(m.n_solves for m in solver)),
                                                   "starts": exact.starts["start"].tolist(), "best_start": best}
            messages += [f"polish start {row.start:<40} solver chi^2 {row.chi2_start:.6g} -> {row.chi2:.6g} "
                         f"(chi^2/dof {row.chi2_dof:.4g}, {row.iterations} iterations)"
                         f"{' <- selected' if row.selected else ''}" for row in exact.starts.itertuples()]
            messages.append(f"polished with the full solver in {time.perf_counter() - start:.1f} s from "
                            f"{len(exact.starts)} starts, the best from {best}: loss {fit.loss:.4g} -> "
                            f"{exact.loss:.4g}, chi^2/dof {exact.chi2_dof:.3g} ({exact.message})")
            fit = exact
        else:
            note = ("the full solver has no periodic solution at the library's best trials (a fold or an unstable "
                    "region next to them): the library's estimate is kept, with the library's error in its weights")
            fit.uncertainty.notes.append(note)
            summary["solver"] = {"failed": note, "seconds": time.perf_counter() - start}
            warnings.append(f"polish failed: {note}")
    if options.get("profile", True):  # a loose shared parameter: the others' intervals over it (profile.py)
        fit = prf.with_profile(fit)
        if fit.profile is not None:
            messages += [f"intervals: {note}" for note in fit.profile.notes]
            messages.append(f"profile of the intervals in {fit.profile.seconds:.1f} s")
            summary["profile"] = {"loose": list(fit.profile.loose), "seconds": fit.profile.seconds,
                                  "fits": int(len(fit.profile.points)), "notes": list(fit.profile.notes)}
    summary["final"] = fit.summary()
    warnings += list(fit.uncertainty.notes)
    return JointFit(fit, library_fit, comparison, summary, data, messages, warnings)


def write_fit_summary(summary: Mapping, path: str | Path) -> None:
    """The joint fit's summary (identification/summary.yaml: ``JointFit.summary``, plain types: library, solver,
    the intervals' profile when a parameter is loose, final); ``read_fit_summary`` is its inverse."""
    with open(path, "w") as stream:
        yaml.safe_dump(dict(summary), stream, sort_keys=False)


def read_fit_summary(path: str | Path) -> dict:
    """A summary written by ``write_fit_summary``: the same mapping (its ``final`` block: the final fit's
    ``Identification.summary``, n_data, dof, chi2, chi2_dof, ...)."""
    with open(path) as stream:
        return dict(yaml.safe_load(stream))


def polish_starts(fit: idn.Identification, variant: Variant, parent_refit: tuple[str, str, pd.DataFrame] | None,
                  nested: Sequence[tuple[Variant, pd.DataFrame]], messages: list[str]) -> tuple[Array, list[str]]:
    """The polish's extra starts after the library optimum (``fit_joint``), theta (k, n) and a label each:
    the next-best library trials; the parent's diagnosis refit with the added effect, when there; each nested
    variant's joint fit mapped onto ``variant`` (entries it lacks from ``fit``) when ``variant`` reproduces it
    (mismatch below ``NESTED_MISMATCH``). What was found or left out is appended to ``messages``."""
    starts = pol.next_best_trials(fit)
    labels = ["library optimum"] + [f"library trial {i + 2}" for i in range(len(starts))]
    if parent_refit is not None:  # this variant adds one effect to another: its diagnosis refit is a start
        parent, extra, refits = parent_refit
        refit = idn.theta_from_table(refits[refits["effect"] == extra], fit.layout)
        messages.append(f"polish also starts from {parent}'s diagnosis refit with {extra}: "
                        f"{'found' if refit is not None else 'not there (not refitted)'}")
        if refit is not None:
            starts = np.vstack([starts, refit[None]])
            labels.append(f"{parent}'s diagnosis refit with {extra}")
    own = fit.table()  # entries a nested fit does not give
    for simpler, table in nested:
        theta, mismatch = theta_from_nested(table, simpler, variant, fit.layout, own)
        usable = theta is not None and mismatch < NESTED_MISMATCH
        verdict = ("a polish start" if usable else "not nested exactly, not used" if theta is not None
                   else "an entry is missing, not used")
        messages.append(f"{simpler.name}'s joint fit mapped onto {variant.name}'s parameters: coefficient mismatch "
                        f"{mismatch:.2g}, {verdict}")
        if usable:
            starts = np.vstack([starts, theta[None]])
            labels.append(f"{simpler.name}'s joint fit")
    return starts, labels



def excluded_table(data: idn.RunData, parameters: Sequence[str], lower: Array, upper: Array,
                   units: Mapping[str, str]) -> pd.DataFrame:
    """The parameter table of a run that cannot be fitted (not usable): ``Identification.table``'s rows and
    columns with NaN estimates, and the reason as its note."""
    rows = [{"parameter": p, "run": data.run, "kind": "physical", "unit": units.get(p, ""), "value": np.nan,
             "lower": float(lo), "upper": float(hi)} for p, lo, hi in zip(parameters, lower, upper)]
    rows.append({"parameter": "phase", "run": data.run, "kind": "nuisance", "unit": "rad", "value": np.nan,
                 "lower": -np.pi, "upper": np.pi})
    table = pd.DataFrame(rows).reindex(columns=list(idn.TABLE_COLUMNS))
    table[["at_bound", "identifiable"]] = False
    table["interval"], table["loose"], table["mc_note"] = "none", "", ""
    table["source"], table["note"] = "library", data.note
    return table


def start_from_runs(layout: Layout, per_run: Mapping[str, idn.Identification]) -> np.ndarray | None:
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


def theta_from_nested(table: pd.DataFrame, parent: Variant, variant: Variant, layout: Layout,
                      fallback: pd.DataFrame) -> tuple[Array | None, float]:
    """A start for ``variant`` from the joint fit (parameter table) of a variant nested in it: the shared values
    mapped onto ``variant``'s unknowns (``hybridtwin.model.variants.embed``), the per-run entries (bow, phases) copied
    run by run, and any entry neither gives taken from ``fallback`` (a table of ``variant``'s own fit). The
    theta (None when an entry is still missing) and the mapping's coefficient mismatch (0: exact)."""
    shared = table[table["run"] == "all"]
    values, mismatch = embed(parent, variant, dict(zip(shared["parameter"], shared["value"].astype(float))))
    mapped = pd.DataFrame({"parameter": list(values), "run": "all", "value": list(values.values())})
    columns = ["parameter", "run", "value"]
    rows = pd.concat([fallback[columns], table.loc[table["run"] != "all", columns], mapped])
    return idn.theta_from_table(rows.drop_duplicates(["parameter", "run"], keep="last"), layout), mismatch


def write_fit(path: str | Path, fit: idn.Identification, rpm: Sequence[float], cycles: int = 2,
              n_time: int = 200) -> None:
    """The fitted response for plotting (zarr v3): per run, measured and fitted harmonics h = 1..H in the
    record's frame, sigmas, and two revolutions of every channel (x, y on the VARM; measured synchronous average
    and fitted); the channels' names in the attribute ``channels``."""
    group = zarr.open_group(str(path), mode="w")
    channels = list(fit.data[0].channels) if getattr(fit, "data", None) else list(idn.CHANNELS)
    fitted = fit.fitted()
    H = fit.X.shape[1]
    angle = np.linspace(0, 2 * np.pi * cycles, n_time, endpoint=False)
    wave = np.exp(1j * np.outer(angle, np.arange(1, H + 1)))  # (T, H)
    arrays = {
        "harmonic": np.arange(1, H + 1), "angle_rad": angle,
        "measured_re_m": fit.X.real, "measured_im_m": fit.X.imag,
        "fitted_re_m": fitted.real, "fitted_im_m": fitted.imag,
        "sigma_m": fit.problem.sigma,
        "measured_wave_m": np.einsum("th,rhc->rtc", wave, fit.X).real,
        "fitted_wave_m": np.einsum("th,rhc->rtc", wave, fitted).real,
    }
    for name, data in arrays.items():
        group.create_array(name, data=np.asarray(data, float))
    group.attrs.update({"runs": list(fit.layout.runs), "rpm": [float(v) for v in rpm],
                        "channels": channels, "chi2_dof": float(fit.chi2_dof),
                        "values": {k: float(v) for k, v in fit.values().items()},
                        "layout": "arrays (run, harmonic, channel); waves (run, time, channel); angle = Omega t"})
    write_manifest(path)

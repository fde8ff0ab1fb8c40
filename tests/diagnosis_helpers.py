"""The diagnosis of records set up one way for the tests and benchmarks that share it (tests/test_machine_candidates.py,
benchmarks/machine_candidates_benchmark.py, benchmarks/ross_faults_diagnosis.py): the base variant fitted to the
records with the full solver, then diagnosed among candidates."""

from __future__ import annotations

import numpy as np

from hybridtwin.diagnose import diagnosis as dg
from hybridtwin.diagnose import score_test as st
from hybridtwin.identify import forward as fwd
from hybridtwin.identify import identification as idn
from hybridtwin.identify import lm
from hybridtwin.identify.protocol import ProtocolOptions
from hybridtwin.settings import diagnosis_settings

#: the base fit: 3 random starts beside the nominal one (seed 2), at most 60 Levenberg-Marquardt iterations each
BASE_FIT = ProtocolOptions(trials=3, monte_carlo=0, seed=2, lm=lm.LMOptions(max_iterations=60))


def fit_and_diagnose(variant, data: list[idn.RunData], candidates: list, harmonics: int,
                     diagnosis: dict | None = None) -> tuple[dg.Diagnosis, idn.Identification]:
    """``variant`` (its unknowns over their ranges) fitted to ``data`` with the full solver (``BASE_FIT``), then
    diagnosed among ``candidates`` with the config's ``diagnosis:`` settings ``diagnosis`` (None: the defaults);
    (the diagnosis, the base fit)."""
    lower, upper = (np.array(v, float) for v in zip(*variant.unknown.values()))
    models = [fwd.SolverModel(variant, d.run, d.rpm, d.eccentric_mass_g, list(variant.unknown), lower, upper,
                              harmonics) for d in data]
    fit = idn.identify(models, data, (), BASE_FIT)
    base = st.BaseFit(variant, fit.layout, fit.theta, fit.data, harmonics)
    options = diagnosis_settings({"diagnosis": diagnosis} if diagnosis else {}).options()
    return dg.diagnose(base, candidates, options), fit

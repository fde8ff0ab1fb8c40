"""Written numbers compared across machines (issue 42): a record or table written by the same command on another
CPU may differ in a last digit (its BLAS kernel moves the solver's round-off); these compare what was written to
a tolerance that says why, never byte for byte."""

from pathlib import Path

import numpy as np
import pandas as pd


def same_record(written: Path, shipped: Path) -> None:
    """The same samples to one unit of the last written digit: the record writes time with 6 decimals and mm with 4
    (rig.write_record). A value of the rig moves by ~1e-9 relative across BLAS kernels (above), so a written digit
    can only flip where a value sits that close to a rounding boundary: one unit, never more; a change of the rig's
    physics or noise moves every sample by far more than 1e-4 mm."""
    header = shipped.read_text().splitlines()[0]
    assert written.read_text().splitlines()[0] == header, written.name
    got, want = (np.loadtxt(p, delimiter=",", skiprows=1) for p in (written, shipped))
    assert got.shape == want.shape, written.name
    unit = np.array([1e-6 if c == "time_s" else 1.0 if c == "keyphasor" else 1e-4 for c in header.split(",")])
    np.testing.assert_array_less(np.abs(got - want), 1.01 * unit + np.zeros_like(got), err_msg=written.name)


def same_table(written: Path, shipped: Path) -> None:
    """truth.tsv parsed: text and flags equal, numbers to rtol 1e-8. The harmonic-balance solution is converged to
    ||r|| <= 1e-10 ||x|| (solver.solve's tol); across BLAS kernels its written values moved by <= 7.3e-10 relative
    (above); 1e-8 keeps a margin of 10 over that and is 1e4 below the smallest physical change the rig can make
    (its noise, 5 um, on responses of ~100 um is 5e-2). A near-zero entry is compared on its column's scale."""
    got, want = (pd.read_csv(p, sep="\t") for p in (written, shipped))
    assert list(got.columns) == list(want.columns) and len(got) == len(want)
    for column in want.columns:
        if pd.api.types.is_float_dtype(want[column]):
            # relative to the column's largest value: a near-zero entry (a mean harmonic) is round-off itself
            scale = np.nanmax(np.abs(want[column])) if want[column].notna().any() else 0.0
            np.testing.assert_allclose(got[column], want[column], rtol=1e-8, atol=1e-8 * scale, err_msg=column)
        else:
            assert got[column].astype(str).tolist() == want[column].astype(str).tolist(), column

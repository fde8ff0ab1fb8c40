"""Every kind of zarr store the workflow writes and reads carries a checksum manifest that its reader checks
(hybridtwin.offline.stores): a deleted chunk never reads as zeros, a truncated one never as a bare codec error; the
error is one line naming the store and the chunk. Stores: snapshot chunks, gathered snapshots, POD bases,
sPGD libraries, fits (joint / per run, and the not-fitted run's store). Synthetic contents, no solver: seconds.
"""

import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
import zarr

from hybridtwin.report import report
from hybridtwin.offline import snapshots
from hybridtwin.offline.library import Library
from hybridtwin.offline.pod import load_pod, pod_of_runs
from hybridtwin import tables
from hybridtwin.identify.run_fits import write_fit, write_run_fit
from hybridtwin.offline.scenarios import RunSolutions
from hybridtwin.model.shaft import Shaft
from hybridtwin.offline.spgd import SparsePGD
from hybridtwin.offline.stores import MANIFEST, CorruptStoreError, check_store, verify_store, write_manifest

RNG = np.random.default_rng(11)  # library and fit contents (any values)
RUNS = ["r500", "r700"]
S, H, N_DOF = 30, 3, 44
PARAMETERS = ["k_b", "zeta_s"]


def _solutions() -> tuple[pd.DataFrame, RunSolutions]:
    """30 scenarios at two runs, converged, small harmonics (inside any sensor range), two unstable points
    (the same at every call)."""
    RNG = np.random.default_rng(3)
    table = pd.DataFrame({"scenario": np.arange(S), "split": ["train"] * 20 + ["validation"] * 5 + ["test"] * 5,
                          "k_b": RNG.uniform(2000, 3500, S), "zeta_s": RNG.uniform(0.01, 0.05, S)})
    harmonics = 1e-4 * (RNG.standard_normal((2, S, H + 1, N_DOF)) + 1j * RNG.standard_normal((2, S, H + 1, N_DOF)))
    radius = RNG.uniform(0.5, 0.9, (2, S))
    radius[1, [3, 7]] = 1.7
    solved = RunSolutions(RUNS, [500.0, 700.0], [25.9, 25.9], harmonics, np.ones((2, S), bool),
                          np.full((2, S), "converged", object), np.full((2, S), "run-up", object), radius)
    return table, solved


def _chunk(folder: Path) -> Path:
    table, solved = _solutions()
    snapshots.write_chunk(folder / "000.zarr", "geometric", table, PARAMETERS, solved)
    return folder / "000.zarr"


def _gathered(folder: Path) -> Path:
    table, _ = _solutions()
    snapshots.save(snapshots.read_chunks([_chunk(folder)], table), folder / "snapshots.zarr")
    return folder / "snapshots.zarr"


def _pod(folder: Path) -> Path:
    pod_of_runs(str(_gathered(folder)), str(folder / "pod.zarr"), Shaft(), 1.0, 1e-10)
    return folder / "pod.zarr"


def _library(folder: Path) -> Path:
    X = RNG.uniform(-1, 1, (60, 2))
    Y = np.c_[1 + X[:, 0] * X[:, 1], X[:, 0] ** 2, np.sin(X[:, 1])]
    model = SparsePGD(degree=4, max_terms=6).fit(X[:45], Y[:45], X[45:], Y[45:])
    modes = np.linalg.qr(RNG.standard_normal((2 * 2 * N_DOF, 3)))[0]
    Library("r500", PARAMETERS, np.array([2000.0, 0.01]), np.array([3500.0, 0.05]), modes, np.ones(3), model, 2,
            N_DOF, [2, 24]).save(folder / "library.zarr")
    return folder / "library.zarr"


def _fit(folder: Path) -> Path:
    """run_fits.write_fit on a duck-typed joint fit of two runs (as tests/test_report.py)."""
    X = 1e-3 * (RNG.standard_normal((2, H, 2)) + 1j * RNG.standard_normal((2, H, 2)))
    fit = SimpleNamespace(X=X, fitted=lambda: 0.9 * X, problem=SimpleNamespace(sigma=np.full((2, H, 2), 1e-6)),
                          layout=SimpleNamespace(runs=tuple(RUNS)), chi2_dof=1.0, values=lambda: {"k_b": 2400.0})
    write_fit(folder / "fit.zarr", fit, [500.0, 700.0])
    return folder / "fit.zarr"


def _read_fit(path: Path):
    parameters = pd.DataFrame({"parameter": ["k_b", "phase", "phase"], "run": ["all"] + RUNS,
                               "kind": ["shared", "nuisance", "nuisance"], "value": [2400.0, 0.1, 0.2],
                               "source": "solver"})
    sheet = pd.DataFrame({"run": RUNS, "eccentric_mass_g": [25.9, 25.9]})
    return report.fit_comparisons(path, parameters, {"n_data": 24, "dof": 20}, sheet)


# kind: (writer, reader, an array with chunks, name in the error)
KINDS = {
    "chunk": (_chunk, lambda p: snapshots.read_chunks([p], _solutions()[0]), "harmonics", "chunk store"),
    "snapshots": (_gathered, snapshots.load, "harmonics", "snapshot store"),
    "pod": (_pod, lambda p: load_pod(str(p), "r500"), "r500/modes", "POD store"),
    "library": (_library, Library.load, "modes", "library store"),
    "fit": (_fit, _read_fit, "fitted_re_m", "fit store"),
}


def _a_chunk(store: Path, array: str) -> Path:
    return min(p for p in (store / array / "c").rglob("*") if p.is_file())


@pytest.mark.parametrize("kind", KINDS)
def test_an_intact_store_reads_and_matches_its_manifest(kind, tmp_path):
    write, read, _, _ = KINDS[kind]
    store = write(tmp_path)
    assert (store / MANIFEST).is_file() and verify_store(store) == []
    (store / ".snakemake_timestamp").touch()  # Snakemake's marker on a directory output is not part of the store
    read(store)


@pytest.mark.parametrize("kind", KINDS)
def test_a_deleted_chunk_fails_with_the_store_and_the_chunk_never_reads_as_zeros(kind, tmp_path):
    write, read, array, what = KINDS[kind]
    store = write(tmp_path)
    lost = _a_chunk(store, array)
    lost.unlink()
    name = lost.relative_to(store).as_posix()
    group = zarr.open_group(str(store), mode="r")
    data = group[array][:]
    assert np.all(data[(0,) * (data.ndim - 1)] == 0)  # the hazard: plain zarr fills the lost chunk with zeros
    with pytest.raises(CorruptStoreError) as error:
        read(store)
    message = str(error.value)
    assert "\n" not in message and f"{what} {store}" in message and f"missing {name}" in message


@pytest.mark.parametrize("kind", KINDS)
def test_a_truncated_chunk_fails_with_the_store_and_the_chunk_not_a_codec_error(kind, tmp_path):
    write, read, array, what = KINDS[kind]
    store = write(tmp_path)
    damaged = _a_chunk(store, array)
    damaged.write_bytes(damaged.read_bytes()[: damaged.stat().st_size // 2])
    name = damaged.relative_to(store).as_posix()
    with pytest.raises(Exception) as plain:  # what a reader without the manifest meets
        zarr.open_group(str(store), mode="r")[array][:]
    assert str(store) not in str(plain.value)  # names no file
    with pytest.raises(CorruptStoreError) as error:
        read(store)
    message = str(error.value)
    assert "\n" not in message and f"{what} {store}" in message and f"changed {name}" in message
    assert "Zstd" not in message and "decompress" not in message.lower()


@pytest.mark.parametrize("kind", KINDS)
def test_a_store_without_its_manifest_is_incomplete(kind, tmp_path):
    write, read, _, what = KINDS[kind]
    store = write(tmp_path)
    (store / MANIFEST).unlink()  # as if its job had been killed before writing it
    with pytest.raises(CorruptStoreError, match=f"{what} .*no manifest.sha256 .incomplete"):
        read(store)


def test_reading_one_run_checks_that_runs_chunks_only(tmp_path):
    """snapshots.load(path, run) reads one run's chunks (the per-run library jobs): it verifies those (and the
    shared arrays), so damage to another run's chunk fails that run's read and the whole read, not this one."""
    store = _gathered(tmp_path)
    (store / "harmonics" / "c" / "1" / "0" / "0" / "0").unlink()  # run 1's steady states
    assert snapshots.load(store, RUNS[0]).harmonics.shape == (1, S, H + 1, N_DOF)
    for run in (RUNS[1], None):
        with pytest.raises(CorruptStoreError, match="missing harmonics/c/1/0/0/0"):
            snapshots.load(store, run)


def test_the_stability_flags_survive_chunk_gather_and_load(tmp_path):
    _, solved = _solutions()
    store = snapshots.load(_gathered(tmp_path))
    np.testing.assert_array_equal(store.stable, solved.stable)
    np.testing.assert_array_equal(store.floquet_radius, solved.floquet_radius)
    assert not store.stable[1, [3, 7]].any() and store.stable.sum() == 2 * S - 2


def test_the_solved_code_survives_chunk_gather_and_load_and_older_stores_read_it_from_messages(tmp_path):
    """``solved`` (an enrichment scenario not solved at a run of another mass) is written by write_chunk, joined by
    read_chunks, saved and loaded (all runs, one run) as written; a store from before the ``solved`` array reads it
    from the NOT_SOLVED prefix its messages had."""
    from hybridtwin.offline.scenarios import NOT_SOLVED

    table, solved = _solutions()
    solved.solved = np.ones((2, S), bool)
    solved.solved[0, [2, 5]] = solved.solved[1, 9] = False
    solved.message[~solved.solved] = f"{NOT_SOLVED} 19.5 g"
    snapshots.write_chunk(tmp_path / "000.zarr", "geometric", table, PARAMETERS, solved)
    joined = snapshots.read_chunks([tmp_path / "000.zarr"], table)
    np.testing.assert_array_equal(joined.solved, solved.solved)
    snapshots.save(joined, tmp_path / "snapshots.zarr")
    np.testing.assert_array_equal(snapshots.load(tmp_path / "snapshots.zarr").solved, solved.solved)
    np.testing.assert_array_equal(snapshots.load(tmp_path / "snapshots.zarr", RUNS[1]).solved, solved.solved[1:])
    assert {(r, s) for r, s in zip(*np.nonzero(~joined.steady & joined.solved))} == {(1, 3), (1, 7)}
    for store in (tmp_path / "000.zarr", tmp_path / "snapshots.zarr"):  # as written before the solved array
        shutil.rmtree(store / "solved")
        write_manifest(store)
    np.testing.assert_array_equal(snapshots.read_chunks([tmp_path / "000.zarr"], table).solved, solved.solved)
    np.testing.assert_array_equal(snapshots.load(tmp_path / "snapshots.zarr").solved, solved.solved)


def test_a_snapshot_store_from_before_the_stability_check_is_refused(tmp_path):
    chunk = _chunk(tmp_path)
    for name in ("stable", "floquet_radius"):
        for file in sorted((chunk / name).rglob("*"), reverse=True):
            file.unlink() if file.is_file() else file.rmdir()
        (chunk / name).rmdir()
    write_manifest(chunk)  # intact, but old
    with pytest.raises(snapshots.StaleStoreError, match="000.zarr: no stability flags"):
        snapshots.read_chunks([chunk], _solutions()[0])


def test_the_store_of_a_run_that_was_not_fitted_has_a_manifest_too(tmp_path):
    # the history of a run not fitted as run_fits makes it: empty, with the table layer's columns (issue 52)
    history = pd.DataFrame(columns=tables.HISTORY.columns)
    result = SimpleNamespace(parameters=pd.DataFrame({"parameter": ["k_b"]}), history=history, fit=None,
                             run="r500", data=SimpleNamespace(note="no 1X above the noise"))
    write_run_fit(result, tmp_path / "parameters.tsv", tmp_path / "history.tsv", str(tmp_path / "fit.zarr"))
    check_store(tmp_path / "fit.zarr", "fit store")
    assert zarr.open_group(str(tmp_path / "fit.zarr"), mode="r").attrs["note"] == "no 1X above the noise"


def test_several_bad_chunk_stores_are_named_in_one_line(tmp_path):
    first, second = _chunk(tmp_path / "a"), _chunk(tmp_path / "b")
    _a_chunk(first, "harmonics").unlink()
    damaged = _a_chunk(second, "success")
    damaged.write_bytes(damaged.read_bytes()[:3])
    table = _solutions()[0]
    with pytest.raises(CorruptStoreError) as error:
        snapshots.read_chunks([first, second], pd.concat([table, table.assign(scenario=table["scenario"] + S)]))
    message = str(error.value)
    assert "\n" not in message and set(error.value.problems) == {str(first), str(second)}
    assert "corrupt or incomplete chunk stores" in message

"""Resilience of the workflow on one machine: kills, reruns from scratch, damaged chunks, failed scenarios.

One configuration, test_workflow's SMALL with two changes, built from scratch once (the
``reference`` fixture) for the geometric variant's outputs up to the identified parameters:
- the geometric k_b range reaches below zero: a negative spring makes the structure unstable
  at rest, so about a fifth of the scenarios have no steady state at any run (test (d));
- a lighter identification protocol (fewer trials and Monte Carlo repeats): the tests are about
  reruns, not accuracy, and this keeps each workflow run to seconds.
The other tests run the same targets elsewhere and compare every result file with the
reference's, byte for byte (tests/workflow_helpers.py: why that is the right "equal").

test_workflow.py already kills a run while its chunks are solved and compares the library
validation table; here the kill comes later (libraries being built), and the comparison covers
every output and checks that the finished jobs were kept, not redone.
"""

import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import zarr

from hybridtwin.offline import snapshots
from hybridtwin.offline.stores import MANIFEST, CorruptStoreError, verify_store, write_manifest
from workflow_helpers import RUNS, SMALL, SNAKEMAKE, compare_results, copy_workflow, snakemake

GEOMETRIC_KB = "k_b: [2000, 3500], zeta_s: [0.01, 0.05], zeta_bup: [0.0, 0.05]"
assert SMALL.count(GEOMETRIC_KB) == 1
CONFIG = (SMALL.replace(GEOMETRIC_KB, GEOMETRIC_KB.replace("[2000, 3500]", "[-1000, 3500]"))
          + "identification: {trials: 10, monte_carlo: 20, joint: {trials: 10, monte_carlo: 0}}\n")
TARGETS = ["results/geometric/pod.tsv", "results/geometric/library_validation.tsv",
           "results/geometric/parameters.tsv", "results/geometric/validation.tsv"]
RESULTS = Path("results") / "geometric"


def _workflow(directory: Path) -> Path:
    copy_workflow(directory)
    (directory / "config" / "config.yaml").write_text(CONFIG)
    return directory


def _run(work: Path, *args: str) -> subprocess.CompletedProcess:
    return snakemake(work, *TARGETS, *args)  # targets first: options such as --forcerun take lists


def _from_scratch(directory: Path) -> Path:
    work = _workflow(directory)
    run = _run(work)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    return work


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    return _from_scratch(tmp_path_factory.mktemp("reference"))


@pytest.fixture(scope="module")
def elsewhere(tmp_path_factory):
    """The same configuration run from scratch in another directory (the damage test then reuses it:
    a copied workflow directory is no substitute, since check_data's schema input is an absolute path,
    so Snakemake reruns everything in a copy)."""
    return _from_scratch(tmp_path_factory.mktemp("elsewhere"))


def test_scenarios_without_a_solution_are_reported_excluded_and_the_run_goes_on(reference):
    results = reference / RESULTS
    scenarios = pd.read_csv(results / "scenarios.tsv", sep="\t").set_index("scenario")
    failures = pd.read_csv(results / "failures.tsv", sep="\t")
    unstable = scenarios.index[scenarios["k_b"] < 0]
    assert 10 <= len(unstable) <= 40  # ~22 % of 100: the configuration does what it says
    # every failed (run, scenario) is listed once with the solver's reason; the unstable ones at every run
    assert not failures.duplicated(["run", "scenario"]).any()
    assert failures["message"].str.len().gt(0).all()
    listed = failures.groupby("run")["scenario"].apply(set)
    for run in RUNS:
        assert set(unstable) <= listed[run]
    reasons = failures.set_index("scenario").loc[unstable, "message"]
    assert reasons.str.contains("unstable").all()
    # the store holds them as failures (NaN), never as zeros, and only them (besides the enrichment
    # scenarios at the runs they were not meant for: NaN too, marked not solved, not failures); failures.tsv
    # also lists the converged points that are unstable (harmonics kept, flagged, left out downstream)
    store = snapshots.load(results / "snapshots.zarr")
    success, harmonics, ids = store.success, store.harmonics, store.scenario
    failed = {(RUNS[r], ids[s]) for r, s in zip(*np.nonzero(~store.steady & store.solved))}
    assert failed == set(zip(failures["run"], failures["scenario"]))
    assert np.isnan(harmonics[~success]).all() and np.isfinite(harmonics[success]).all()
    unstable = failures["message"].str.startswith("unstable periodic solution")
    assert unstable.sum() == (success & ~store.stable).sum()
    # excluded downstream: the library was built and scored on the converged scenarios only
    validation = pd.read_csv(results / "library_validation.tsv", sep="\t").set_index("run")
    test_ids = scenarios.index[scenarios["split"] == "test"]
    for run in RUNS:
        failed_tests = len(set(test_ids) & listed[run])
        assert validation.loc[run, "n_failed"] + validation.loc[run, "n_unstable"] == failed_tests > 0
        assert 0 < validation.loc[run, "n_test"] <= len(test_ids) - failed_tests
    # and the run went on to the identification
    parameters = pd.read_csv(results / "parameters.tsv", sep="\t")
    assert len(parameters) > 0 and np.isfinite(parameters["value"]).all()
    log = (reference / "logs" / "geometric" / "gather_snapshots.log").read_text()
    assert "without a periodic solution" in log


def test_same_seed_gives_identical_results_from_scratch_elsewhere(reference, elsewhere):
    work = elsewhere
    for name in ["snapshots.zarr", "pod.zarr", "parameters.tsv"] + [f"library/{run}.zarr" for run in RUNS]:
        assert (work / RESULTS / name).exists()
    assert compare_results(reference, work) == []  # libraries, parameters and every other file, bit for bit


def _mtimes(paths) -> dict[str, int]:
    return {str(p): p.stat().st_mtime_ns for p in paths}


def test_run_killed_while_building_libraries_resumes_to_identical_results(reference, tmp_path):
    work = _workflow(tmp_path)
    process = subprocess.Popen([*SNAKEMAKE, "--cores", "2", *TARGETS], cwd=work, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 300
    while not list((work / "logs" / "geometric").glob("spgd_library*.log")) and time.time() < deadline:
        assert process.poll() is None, "the run ended before it could be killed"
        time.sleep(0.1)
    os.killpg(process.pid, signal.SIGKILL)  # a hard kill: the lock and incomplete outputs stay behind
    process.wait()
    assert not (work / RESULTS / "parameters.tsv").exists()
    libraries = [work / RESULTS / "library" / f"{run}.zarr" for run in RUNS]
    assert not all((library / "zarr.json").exists() for library in libraries)  # killed mid-stage
    done_before = _mtimes(sorted((work / RESULTS / "chunks").glob("*.zarr")) + [work / RESULTS / "snapshots.zarr"])
    assert len(done_before) == 3

    locked = _run(work)
    assert locked.returncode != 0 and "LockException" in locked.stdout + locked.stderr
    assert snakemake(work, "--unlock").returncode == 0
    resumed = _run(work, "--rerun-incomplete")
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert _mtimes(Path(p) for p in done_before) == done_before  # finished jobs kept, not redone
    assert "rule solve_chunk:" not in resumed.stdout + resumed.stderr
    assert compare_results(reference, work) == []


def test_damaged_or_missing_chunk_is_detected_and_rebuilt_not_read_as_zeros(reference, elsewhere):
    work = elsewhere  # damaged in place: the last test to use it
    library_stage = ["results/geometric/library_validation.tsv"]
    # as if the run had stopped after the chunk jobs: gather and the library stage have not run yet
    for name in ("snapshots.zarr", "failures.tsv", "pod.zarr", "pod.tsv", "library", "library_validation.tsv",
                 "library_parity.png"):
        path = work / RESULTS / name
        shutil.rmtree(path) if path.is_dir() else path.unlink()
    chunks = work / RESULTS / "chunks"
    # then 000 loses one zarr chunk file, which zarr reads as the fill value: zeros where harmonics were
    lost = chunks / "000.zarr" / "harmonics" / "c" / "1" / "0" / "0" / "0"
    lost.unlink()
    harmonics = zarr.open_group(str(chunks / "000.zarr"), mode="r")["harmonics"][:]
    assert (harmonics[2] == 0).all()  # what the manifest check guards against
    # and 001 gets a flipped byte in its success flags
    flipped = chunks / "001.zarr" / "success" / "c" / "0" / "0"
    data = bytearray(flipped.read_bytes())
    data[-1] ^= 0xFF
    flipped.write_bytes(bytes(data))

    gather = snakemake(work, *library_stage)
    output = gather.stdout + gather.stderr
    assert gather.returncode != 0
    assert "000.zarr: missing harmonics/c/1/0/0/0" in output and "001.zarr: changed success/c/0/0" in output
    assert not (chunks / "000.zarr").exists() and not (chunks / "001.zarr").exists()  # removed, to be rebuilt
    assert not (work / RESULTS / "snapshots.zarr").exists()

    rebuilt = snakemake(work, *library_stage)
    assert rebuilt.returncode == 0, rebuilt.stderr[-3000:]
    assert (rebuilt.stdout + rebuilt.stderr).count("rule solve_chunk:") == 2
    assert verify_store(chunks / "000.zarr") == [] and verify_store(chunks / "001.zarr") == []
    assert compare_results(reference, work) == []  # the rebuilt chunks, store and libraries are the reference's


def test_gathered_store_is_verified_when_read(reference, tmp_path):
    store = tmp_path / "snapshots.zarr"
    shutil.copytree(reference / RESULTS / "snapshots.zarr", store)
    assert snapshots.load(store, RUNS[1]).success.shape == (1, 120)  # 100 hypercube + 20 enrichment scenarios
    (store / "harmonics" / "c" / "1" / "0" / "0" / "0").unlink()  # run 1's steady states
    with pytest.raises(CorruptStoreError, match="missing harmonics/c/1/0/0/0"):
        snapshots.load(store, RUNS[1])


def test_verify_store_names_every_kind_of_damage(tmp_path):
    store = tmp_path / "store.zarr"
    group = zarr.open_group(str(store), mode="w")
    group.create_array("a", data=np.arange(1000.0), chunks=(100,))
    assert verify_store(store) == ["no manifest.sha256 (incomplete: its job did not finish writing it)"]
    assert verify_store(store, require_manifest=False) == []
    write_manifest(store)
    assert (store / MANIFEST).read_text().count("\n") == 12  # zarr.json x 2 and 10 chunks
    (store / ".snakemake_timestamp").touch()  # Snakemake's marker is not part of the store
    assert verify_store(store) == []
    (store / "a" / "c" / "3").unlink()
    (store / "a" / "c" / "4").write_bytes(b"garbage")
    (store / "a" / "c" / "99").write_bytes(b"stray")
    assert verify_store(store) == ["missing a/c/3", "changed a/c/4", "unlisted a/c/99"]
    assert verify_store(tmp_path / "absent.zarr") == ["store missing"]

"""Candidate effects at a machine's named bearings, sized to each bearing (src/hybridtwin/model/bearing_candidates.py):
offered by the machine, none on the VARM (its defaults unchanged), their physics against an independent model,
and the config's use of them (a one-line entry under diagnosis: candidates; the default on a machine of your own).
"""

import numpy as np
import pytest
import scipy.linalg
import yaml
from example_machines import STEPPED_YAML

from hybridtwin import config as cfg
from hybridtwin.model.machine import Machine
from hybridtwin.model.model import Model


def _machine(k_b: float = 1e7) -> Machine:
    spec = yaml.safe_load(STEPPED_YAML)["machine"]
    spec["bearings"]["b"]["k"] = k_b
    return Machine.from_mapping(spec)


def test_every_bearing_with_coefficients_offers_candidates_sized_to_it():
    effects = _machine().effects()
    expected = {  # name: (parameter, half range, limit) = fractions of the bearing's k = 2e7, 1e7 or c = 800, 500
        "bearing_anisotropy@a": ("dk_a", 0.2 * 2e7, 0.5 * 2e7),
        "cross_coupled_stiffness@a": ("kxy_a", 0.01 * 2e7, 0.1 * 2e7),
        "cross_coupled_damping@a": ("cxy_a", 0.4 * 800, 4 * 800),
        "bearing_anisotropy@b": ("dk_b", 0.2 * 1e7, 0.5 * 1e7),
        "cross_coupled_stiffness@b": ("kxy_b", 0.01 * 1e7, 0.1 * 1e7),
        "cross_coupled_damping@b": ("cxy_b", 0.4 * 500, 4 * 500),
    }
    for name, (parameter, half, limit) in expected.items():
        (p,) = effects[name].parameters
        assert (p.name, p.bounds, p.limits, p.nominal) == (parameter, (-half, half), (-limit, limit), 0.0), name
        assert effects[name].switches == (parameter,)
    # the VARM's bearings carry no nominal coefficients: it offers none, so its models and defaults are unchanged
    assert not [name for name in Machine.varm().effects() if name.split("@")[0] in
                ("bearing_anisotropy", "cross_coupled_stiffness", "cross_coupled_damping")]


def _natural_frequencies(machine: Machine, effects: list, values: dict) -> np.ndarray:
    """Undamped natural frequencies at rest (rad/s), sorted, of the machine with ``effects`` at ``values``."""
    model = Model(effects, machine)
    system = model.system(values | {k: p.nominal for k, p in model.parameters.items() if k not in values}, 0.0)
    return np.sort(np.sqrt(np.abs(scipy.linalg.eigvals(system.K[0], system.M[0]).real)))


def test_an_anisotropic_bearing_splits_the_planes_as_two_isotropic_machines():
    """Independent check: at rest, without gyroscopic coupling, the x and y planes do not couple, so a bearing
    stiffer by dk along x and softer by dk along y has the x-plane frequencies of the isotropic machine with
    k + dk and the y-plane ones of k - dk (each isotropic machine has every frequency twice, once per plane)."""
    dk = 1.5e6
    machine = _machine()
    fx = machine.effects()
    aniso = _natural_frequencies(machine, [fx["linear_bearing@a"], fx["linear_bearing@b"],
                                           fx["bearing_anisotropy@b"]], {"dk_b": dk})
    halves = []
    for k in (1e7 + dk, 1e7 - dk):
        other = _machine(k)
        f = other.effects()
        iso = _natural_frequencies(other, [f["linear_bearing@a"], f["linear_bearing@b"]], {})
        halves.append(iso[::2])  # one of each pair
    # the same eigenproblem sizes and matrices up to the assembly's round-off: 1e-9 relative
    np.testing.assert_allclose(aniso, np.sort(np.concatenate(halves)), rtol=1e-9)


def test_cross_coupled_terms_are_skew_at_the_bearings_node():
    """K[u, v] = +kxy, K[v, u] = -kxy (a force kxy (-v, u) along the rotation), the damping likewise, at node 13."""
    machine = _machine()
    fx = machine.effects()
    base = [fx["linear_bearing@a"], fx["linear_bearing@b"]]
    model = Model(base + [fx["cross_coupled_stiffness@b"], fx["cross_coupled_damping@b"]], machine)
    values = {k: p.nominal for k, p in model.parameters.items()} | {"kxy_b": 3e4, "cxy_b": 70.0}
    nominal = {k: p.nominal for k, p in model.parameters.items()}
    with_, without = model.system(values, 1000.0), model.system(nominal, 1000.0)
    u, v = machine.dof("u13"), machine.dof("v13")
    dK, dC = with_.K[0] - without.K[0], with_.C[0] - without.C[0]
    expected_K, expected_C = np.zeros_like(dK), np.zeros_like(dC)
    expected_K[u, v], expected_K[v, u] = 3e4, -3e4
    expected_C[u, v], expected_C[v, u] = 70.0, -70.0
    np.testing.assert_array_equal(dK, expected_K)
    np.testing.assert_array_equal(dC, expected_C)


def test_the_default_candidates_of_a_machine_are_those_at_its_bearings():
    config = yaml.safe_load(STEPPED_YAML)
    # at each bearing its six, then the 2X and 3X forces at each bearing and unbalance plane, the faults (issue 54:
    # looseness and misalignment at each bearing, a crack and a rub at each unbalance plane), and speed damping
    at = ["bearing_anisotropy", "cross_coupled_stiffness", "cross_coupled_damping", "bearing_compliance",
          "moment_stiffness", "bearing_speed_damping"]
    assert cfg.candidate_names(None, config) == (
        [f"{kind}@{b}" for b in "ab" for kind in at]
        + [f"excitation_{h}x@{place}" for place in ("a", "b", "d1") for h in (2, 3)]
        + [f"{fault}@{b}" for b in "ab" for fault in ("looseness", "misalignment")]
        + ["crack@d1", "rub@d1", "speed_damping"])
    assert cfg.candidate_names(["cross_coupled_stiffness@b"], config) == ["cross_coupled_stiffness@b"]
    assert cfg.candidate_names(None, {}) is None  # the VARM: every built-in candidate
    assert {"bearing_anisotropy@b", "excitation_2x@b"} <= set(cfg.candidate_effects(config))


@pytest.fixture
def project(tmp_path, monkeypatch):
    """The example machine's project (examples/stepped_rotor) without any effects file: its variants, rig truth
    and candidates at the bearings must come from the machine alone."""
    import shutil
    from pathlib import Path

    example = Path(__file__).resolve().parents[1] / "examples" / "stepped_rotor"
    (tmp_path / "config").mkdir()
    shutil.copy(example / "runs.tsv", tmp_path / "runs.tsv")
    config = yaml.safe_load((example / "config" / "config.yaml").read_text())
    config["effects_files"] = []
    monkeypatch.chdir(tmp_path)
    return tmp_path, Path(__file__).resolve().parents[1] / "src" / "hybridtwin" / "config.schema.yaml", config


@pytest.mark.parametrize("name, problem", [
    ("bearing_anisotropy@b", None),
    ("cross_coupled_damping@a", None),
    ("bearing_anisotropy@c", "no candidate effect named 'bearing_anisotropy@c'"),
])
def test_a_candidate_at_a_bearing_is_one_line_of_the_config(project, name, problem):
    from hybridtwin.config import ConfigError, check

    folder, schema, config = project
    config["diagnosis"]["candidates"] = [name]
    path = folder / "config" / "config.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    try:
        check(config, schema, [path])
        problems = []
    except ConfigError as err:
        problems = err.problems
    if problem is None:
        assert problems == []
    else:
        # one line naming the entry, and the near names the user may have meant (the same candidate elsewhere)
        assert [p for p in problems if problem in p and "bearing_anisotropy@" in p.split(problem)[1]], problems

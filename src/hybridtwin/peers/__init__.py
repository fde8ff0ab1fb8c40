"""Beside stage 2, the peers: our model and solvers held against another program's on the same rotor and fault
(ROSS's own fault simulations, ``ross_faults``; the cases compared, ``ross_fault_cases``). A comparison harness, not
part of the method: the tests and benchmarks use it, and no stage imports it (issue 52)."""

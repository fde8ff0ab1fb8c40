"""Stage 2, the solvers: periodic steady states by harmonic balance, continuation along a speed sweep, stability
(Floquet multipliers) and the independent time integration."""

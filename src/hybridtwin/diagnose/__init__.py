"""Stage 6, the diagnosis: which physical effect the fitted model misses (score test, refits, forward selection)
or the fingerprint of a discrepancy no candidate explains."""

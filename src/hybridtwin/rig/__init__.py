"""Beside stage 4, the virtual rig: measured-format records (runs sheet, records, answer key) from a truth model with
hidden effects, steady runs (``rig``) and run-ups and coast-downs (``sweep``), what both share (``base``). It runs
the solvers and writes in the data stage's formats; the data stage reads measurements only (issue 52)."""

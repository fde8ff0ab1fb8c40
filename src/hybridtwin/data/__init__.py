"""Stage 4, the measurements (black box): the runs sheet and records, their checks, the order analysis that turns a
record into harmonics with uncertainties (the virtual rig that writes records from a truth model is a stage of its
own, ``rig``)."""

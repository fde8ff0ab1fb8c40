"""Stage 3, the offline library (white box): scenarios of the unknown parameters, their steady states stored as
snapshots, POD and the sparse PGD library that gives the response and its Jacobian in microseconds."""

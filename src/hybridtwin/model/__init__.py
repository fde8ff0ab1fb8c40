"""Stage 1, the model: the finite-element shaft or a machine of one's own, the physical effects (each a
self-describing object), their composition into a model, the model variants a workflow fits, and the sensors."""

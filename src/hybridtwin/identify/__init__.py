"""Stage 5, identification (grey box): forward maps (library or full solver), Levenberg-Marquardt, the paper's
protocol, the polish on the full solver, uncertainty, and the validation runs' predictions."""

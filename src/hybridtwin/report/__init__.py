"""Stage 7, the report: where each variant fails, the ledger, the answer-first summary and the figures engineers
read (Campbell, modes, Bode and polar)."""

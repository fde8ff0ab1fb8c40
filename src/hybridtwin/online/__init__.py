"""The twin online (issue 40): a new record judged against a built twin, without rebuilding it.

``twin``: what a built twin's folder holds (its card ``twin.yaml``, the joint fit's parameters and their
correlation) and the prior it gives a new record; ``intake``: a record or a runs sheet read and checked as
check-data does; ``fits``: the record's fits with the twin as the prior, batched on the full solver; ``assess``:
the verdict (consistent, changed, new discrepancy) and its tables; ``trend``: the history of a twin's
assessments; ``assess_plots``: the one-page figure. The command line: ``hybridtwin assess`` (cli/assess.py).
"""

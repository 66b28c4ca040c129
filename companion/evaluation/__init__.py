"""Evaluation: the paper's SRUM metric, Table I, label-based scores, AUROC and HTML reports.

Nothing here runs on the vehicle; it answers "how good is this summary?" on the bench.
"""

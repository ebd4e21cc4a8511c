"""Stage 5, runs: the paper's pipeline and reproduction, their reports, plots and rerun logs, saved runs and
provenance.
"""

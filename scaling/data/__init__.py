"""Stage 2, data: recordings of simulated machines (dig cycles and static holds), the product line's
machines and matched (source, target) rows, and the δ1 pair data sets the models learn from.
"""

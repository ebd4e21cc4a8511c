"""Stage 4, evaluation: error metrics and row filters, the miniature validation, leave-machine-out
proof over a product line, and intervals and error scores calibrated on held-out machines.
"""

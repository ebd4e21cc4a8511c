"""Stage 1, dimensional analysis: units and dimension matrices, Π groups, the exact Buckingham-Pi
sets, scoring and selection of a group set, and the distortion and prediction factors (Eq. 17-22).
"""

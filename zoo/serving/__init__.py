"""Serving δ1 scaling models: scale F21 from a source machine to a target, in batches, row by row or streamed.

See :class:`ScalingModel` (``zoo.load("ffnn-eq10")`` returns one) and :mod:`zoo.serving.stream`.
"""

from zoo.serving.inputs import InputError, read_table, write_table
from zoo.serving.model import EndStopWarning, ExtrapolationWarning, ScaledForce, ScalingModel, SourceWarning
from zoo.serving.stream import Prediction, Stream

__all__ = ["EndStopWarning", "ExtrapolationWarning", "InputError", "Prediction", "ScaledForce", "ScalingModel",
           "SourceWarning", "Stream", "read_table", "write_table"]

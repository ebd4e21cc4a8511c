"""Shared fixtures of the scaling tests: one tiny simulated data set per session (ER12 + WA475, dig + hold)."""

from __future__ import annotations

import pandas as pd
import pytest
import torch

from scaling.data.recordings import TINY, generate_frame

torch.set_num_threads(1)


@pytest.fixture(scope="session")
def tiny_frame() -> pd.DataFrame:
    """:data:`scaling.data.recordings.TINY` simulated in memory: 3 dig cycles and 2 static holds per machine (~4 s)."""
    return generate_frame(TINY)

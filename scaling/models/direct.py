"""Direct Buckingham-Pi scaling: δ1 ≡ 1, i.e. π_1(target) = π_1(source) (Eq. 14); the paper's baseline."""

from __future__ import annotations

import numpy as np

from scaling.data.delta_dataset import DeltaDataset
from scaling.models.base import Data, DeltaModel


class DirectPi(DeltaModel):
    """Ignores distortions: predicts δ1 = 1 (ln δ1 = 0) for every pair. Paper: 42 % error on the miniature."""

    name = "DirectPi"

    def _fit(self, dataset: DeltaDataset) -> None:
        pass

    def _predict_log(self, data: Data) -> np.ndarray:
        n = len(data) if isinstance(data, DeltaDataset) else np.asarray(data).shape[0]
        return np.zeros(n)

    def _summary(self) -> str:
        return "δ1 ≡ 1 (no distortion correction)"

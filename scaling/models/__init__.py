"""δ1 models: one ``fit(dataset) / predict(X or dataset) / score(dataset) -> R²`` interface, persisted without pickle.

All learn ``ln δ1 = f(g_2..g_n)`` with δ1 = π_1(source)/π_1(target) (paper Eq. 16/20) and g_n the generalised log
distortions (:class:`scaling.dimensions.factors.LogDistortion`).

* :class:`DirectPi`: δ1 ≡ 1 (direct Buckingham-Pi scaling, the baseline);
* :class:`PowerLaw`: ln δ1 = Σ a_n g_n + b (least squares);
* :class:`FFNN`: MLP; :class:`GRUModel`: recurrent over each episode; :class:`DeepEnsemble`: Gaussian MLP ensemble
  with predictive intervals.
"""

from scaling.models.base import DeltaModel, load_model, model_class, r2_score
from scaling.models.direct import DirectPi
from scaling.models.ensemble import DeepEnsemble, GaussianFFNN
from scaling.models.ffnn import FFNN
from scaling.models.gru import GRUModel
from scaling.models.power_law import PowerLaw

__all__ = ["FFNN", "DeepEnsemble", "DeltaModel", "DirectPi", "GRUModel", "GaussianFFNN", "PowerLaw", "load_model",
           "model_class", "r2_score"]

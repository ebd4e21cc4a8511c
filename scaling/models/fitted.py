"""What validation, the zoo builder and serving read off a fitted δ1 model, light enough for serving.

* :func:`model_groups`: π1 and the input groups the model was trained on (from its ``groups_``, the
  :meth:`scaling.data.delta_dataset.DeltaDataset.groups_dict` of its training pairs).
* :data:`STATIC_STEPS`: how a recurrent model sees a machine at rest: one static row repeated as a constant sequence
  of this many steps, read at the last step (the miniature validation,
  :func:`scaling.evaluation.miniature.static_pairs`, and serving of lone target rows,
  :meth:`zoo.serving.ScalingModel.scale_force`).

Imports only :mod:`scaling.dimensions.groups`, so that :mod:`zoo.serving` loads neither the simulator (MuJoCo) nor
matplotlib.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from scaling.dimensions.groups import PiGroup

if TYPE_CHECKING:
    from scaling.models import DeltaModel

#: Length of the constant sequence a recurrent model sees per static row (machine at rest).
STATIC_STEPS = 30


def model_groups(model: DeltaModel) -> tuple[PiGroup, tuple[PiGroup, ...]]:
    """π1 and the input groups a fitted model was trained on.

    Raises:
        RuntimeError: the model is not fitted (it has no groups yet).
    """
    if model.groups_ is None:
        raise RuntimeError(f"{model.name} is not fitted")
    return (PiGroup.from_dict(model.groups_["output"]),
            tuple(PiGroup.from_dict(g) for g in model.groups_["inputs"]))

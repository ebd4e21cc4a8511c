"""scaling: Buckingham-Pi groups, group-set selection and distortion-aware scaling of digital twins."""

from scaling.groups import PiGroup
from scaling.pi_theorem import PiSet, enumerate_pi_sets, pi_groups, read_manifest, write_manifest
from scaling.selection import (
    CrossValidatedR2,
    MutualInformation,
    PearsonRMS,
    Scorer,
    SpearmanRMS,
    rank_pi_sets,
    select_pi_set,
)

__all__ = [
    "CrossValidatedR2",
    "MutualInformation",
    "PearsonRMS",
    "PiGroup",
    "PiSet",
    "Scorer",
    "SpearmanRMS",
    "enumerate_pi_sets",
    "pi_groups",
    "rank_pi_sets",
    "read_manifest",
    "select_pi_set",
    "write_manifest",
]

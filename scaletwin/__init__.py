"""scaletwin: scale calibrated digital twins across machine sizes.

Layers, bottom to top: :mod:`scaletwin_envs` (physics: MuJoCo loaders, soil, signals, recordings),
:mod:`scaling` (dimensional analysis and distortion-aware models), :mod:`zoo` (checkpoints) and this package's
command line (:mod:`scaletwin.cli`).
"""

__version__ = "0.1.0"

"""Statistics stage: sensor-noise model, the null (perturbed replays), localisation with FDR control, redundancy."""

"""Twin stage: the twin's spec, the env with the catalogue's hooks, planting effects and (parallel, cached) replays."""

"""The one error the zoo raises for anything wrong with a checkpoint."""


class CheckpointError(Exception):
    """A checkpoint is missing, malformed, tampered with, or of a kind no builder knows; nothing was loaded."""

"""Training, checkpoints, evaluation and metrics."""

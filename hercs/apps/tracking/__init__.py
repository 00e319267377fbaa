"""Experiment tracking: a run's epochs, config, commit and videos sent to TensorBoard, W&B
or MLflow."""

"""Evaluation metrics for generated motion."""

"""Training: data loading from prepared windows, the trainer loop, checkpoints and resume."""

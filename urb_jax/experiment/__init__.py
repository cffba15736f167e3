"""Experiments: URB's protocol, the human phase, the hybrid trainer, checkpoints."""

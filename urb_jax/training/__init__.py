"""The trainers: URB's day-by-day protocol, the shared human phase, the hybrid trainer and its
round checkpoints."""

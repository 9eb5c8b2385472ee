"""Training our own intensity-reconstruction weights on our simulator's data (data, losses, loop, evaluation)."""

"""Metrics against ground truth: geometry, trajectories and images."""

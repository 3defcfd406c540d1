"""Comparisons of the model with measured data."""

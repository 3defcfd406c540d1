"""Discrepancy workflow: where the model and the data disagree, and which effect explains it."""

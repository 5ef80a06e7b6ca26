"""Experiments: the comparison, campaigns, domain studies and accuracy."""

"""Experiments: the comparison, campaigns, domain studies, accuracy and reachability."""

"""Launch: the supervisor of the four service processes, ``umay run`` (one bounded run),
``umay up`` (keep them running) and ``umay status`` (ask them how they are)."""

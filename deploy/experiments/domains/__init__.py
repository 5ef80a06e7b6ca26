"""``umay domains``: how far from its goal each strategy still converges, over a grid of large
initial displacements (docs/domains.md).

Modules: :mod:`.study` (the grid, its draws and the judging of each run; pure), :mod:`.run`
(executors: the runs in this process, on local worker processes or on a Dask cluster),
:mod:`.report` (the study's tables and heat maps) and :mod:`.cli` (the command).
"""

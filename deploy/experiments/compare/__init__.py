"""``umay compare``: every Jacobian strategy on every scenario of a suite, side by side.

The thesis's experiment (§5.6-5.7: constant, dynamic, PMJ and MPJ Jacobians), extended with
``points3d`` and with a scenario suite (``deploy/scenarios/suite``). Each (scenario, strategy)
pair is one lockstep :func:`deploy.launch.run.run_once`: its own four service processes, its own
key prefix and its own listening port, so several pipelines share a machine without
crosstalk, and every run is deterministic (only the wall time varies).

Functional core (pure, tested without processes): :func:`plan` validates the whole
comparison before anything starts, :class:`CompareRow` is one run, :func:`rows_csv` /
:func:`rows_json` and their inverses write and read the results, :func:`summarize_modes`,
:func:`best_per_metric` and :func:`summary_markdown` aggregate them, :func:`differences`
compares two comparisons. Imperative shell: :func:`run_all` (a thread per running job, each
waiting on its own processes), :func:`make_figures`, :func:`write_outputs`; the command line
is in :mod:`deploy.experiments.cli`.

Outputs in ``--out``: ``results.csv``, ``results.json``, ``summary.md``, ``logs/`` (each run's
service logs) and ``figures/`` (per strategy, the thesis-style figures of the figures
scenario, its MCAP recording, and ``overlay.png`` of all strategies).

Modules: :mod:`.plan` (validate the whole comparison first), :mod:`.rows` (one run's row, CSV
and JSON, comparing two comparisons), :mod:`.summary` (per strategy, the tables and
``summary.md``), :mod:`.run` (the runs, the figures, the outputs), :mod:`.plots` (the figures
across strategies).
"""

from __future__ import annotations

from common.config import JacobianMode

ALL_MODES = tuple(m.value for m in JacobianMode)


class CompareError(ValueError):
    """Bad input to ``umay compare``; the message names what and why. Nothing was launched."""

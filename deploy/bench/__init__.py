"""``umay bench``: the loop's latency and throughput, stage by stage, distributed and in-process.

Three measurements in one command, on the same scenario and image size, by module:

1. **Distributed** (:mod:`~deploy.bench.distributed`): the real four services as separate OS
   processes, every camera frame split into consecutive stages (:mod:`~deploy.bench.stages`)
   from the stamps the services and the sim report (:mod:`~deploy.bench.trace`), with each
   process's CPU time and memory (:mod:`~deploy.bench.processes`).
2. **In-process baseline** (:mod:`~deploy.bench.inprocess`): the same pipeline in this process
   on the same frames, the services' pure steps timed one by one, and the codec work apart.
3. **Synthetic 30 Hz source** (:mod:`~deploy.bench.synthetic`): frames replayed at the camera's
   rate into vision → controller → actuation as processes.

The renderers' cost (:mod:`~deploy.bench.render`) comes with them. :mod:`~deploy.bench.run`
composes the whole benchmark into one typed report (:mod:`~deploy.bench.report`, the JSON
written), :mod:`~deploy.bench.text` prints it, with the run against issue 26's goals
(:mod:`~deploy.bench.goals`), and :mod:`~deploy.bench.cli` is the command.
This package's top holds only what every part raises, so that the command's parser and the
live view's bench hook import nothing heavy.
"""

from __future__ import annotations


class BenchError(RuntimeError):
    """The benchmark could not run (a service died or did not come up, no frames...)."""

"""Imported by the services' forkserver alone (:data:`deploy.service_process.PRELOAD`), never
by the supervisor or a service: the forkserver ignores SIGTERM, as multiprocessing already has
it ignore SIGINT.

A SIGTERM sent to a whole process group (``timeout``, ``kill -- -PGID``, a CI job cancelled)
reaches the services, which stop cleanly, and their supervisor, which waits for them. Their
exit codes come from the forkserver, whose children they are: killed with them, it could not
report any (every one read 255, as if they had crashed). It still ends with the supervisor,
when the pipe that keeps it alive closes. A forked service puts SIGTERM back to its default
first thing (:func:`deploy.service_process.serve`)."""

import signal

signal.signal(signal.SIGTERM, signal.SIG_IGN)

"""Imported by the services' forkserver alone (:data:`deploy.service_process.PRELOAD`, first),
never by the supervisor or a service: the forkserver blocks SIGTERM and SIGINT.

A SIGTERM sent to a whole process group (``timeout``, ``kill -- -PGID``, a CI job cancelled)
reaches the services, which stop cleanly, and their supervisor, which waits for them. Their
exit codes come from the forkserver, whose children they are: killed with them, it could not
report any (every one read 255, as if they had crashed). It still ends with the supervisor,
when the pipe that keeps it alive closes.

Multiprocessing has the forkserver ignore SIGINT only once its imports are done: a Ctrl-C
during them ended it, and with it the run. The process that starts the forkserver
(:func:`deploy.service_process.fork_service`) blocks both signals while it does, so the
forkserver starts with them blocked; this module, first of the preload, keeps them so for good
(the main script, imported before the preload, is covered by the inherited mask).

Blocked, not ignored: a forked service inherits the mask, and unblocks both first thing
(:func:`deploy.service_process.serve`), so one sent to it before then is held, then delivered,
not lost (ignored, it was dropped, and the service had to be killed)."""

import signal

signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGTERM, signal.SIGINT})

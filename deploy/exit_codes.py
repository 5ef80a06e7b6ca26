"""Exit codes of every ``umay`` command, in one place (docs/operations.md lists them)."""

EXIT_OK = 0  # converged, done, no difference found
EXIT_FAILED = 1  # not converged, a difference found, a run or a service failed
EXIT_BAD_INPUT = 2  # an option or a scenario refused before anything was started
EXIT_ALREADY_RUNNING = 3  # another supervisor holds the key prefix
EXIT_INTERRUPTED = 130  # Ctrl-C or SIGTERM: what was started has been stopped

# umay run's names for the first two.
EXIT_CONVERGED = EXIT_OK
EXIT_NOT_CONVERGED = EXIT_FAILED

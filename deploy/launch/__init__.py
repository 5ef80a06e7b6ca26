"""Launch: ``umay run`` (one bounded run: checked before launch, judged at its end), ``umay
up`` (keep the services running) and ``umay status`` (ask them how they are); the processes
themselves are :mod:`deploy.supervisor`'s."""

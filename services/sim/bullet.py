"""pybullet, imported without its build-time banner.

pybullet's module initialisation prints ``pybullet build time: <date>`` on standard error, once
per process: the first line of ``umay run``'s output and of the sim's log, telling a user
nothing. The sim imports pybullet from here: standard error's descriptor points at
``/dev/null`` while the module loads (C's stdio flushed before it is put back), and only then."""

from __future__ import annotations

import ctypes
import os
import sys


def _import_quietly() -> None:
    if "pybullet" in sys.modules:
        return
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:  # no standard error to protect
        import pybullet

        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        try:
            import pybullet  # noqa: F401
        finally:
            ctypes.CDLL(None).fflush(None)
            os.dup2(saved, 2)
    finally:
        os.close(saved)


_import_quietly()

import pybullet  # noqa: E402  (loaded above, quietly)
from pybullet_utils.bullet_client import BulletClient  # noqa: E402

__all__ = ["BulletClient", "pybullet"]

"""A supervised process ends with its supervisor, however the supervisor ends (SIGKILL too).

The supervisor starts each child in a session of its own (a terminal's Ctrl-C reaches only the
supervisor, which stops them in order), so nothing else would tell a child that its supervisor is
gone: it would hold its ports for ever. The supervisor names itself in `PARENT_ENV`; the child asks
Linux for SIGTERM when that parent dies (prctl PR_SET_PDEATHSIG) and stops as on any SIGTERM.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
from collections.abc import MutableMapping

PARENT_ENV = "GRIDFLEET_SUPERVISOR_PID"
PR_SET_PDEATHSIG = 1  # linux/prctl.h


def die_with_parent(environ: MutableMapping[str, str] = os.environ) -> bool:
    """When a supervisor started this process: SIGTERM on its death; whether that is armed."""
    # Taken out, so a process this one starts is not mistaken for the supervisor's own child.
    parent = environ.pop(PARENT_ENV, None)
    if parent is None or not sys.platform.startswith("linux"):
        return False
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0) != 0:
        return False
    if os.getppid() != int(parent):
        # The supervisor died before the prctl above: nobody is left to signal us.
        os.kill(os.getpid(), signal.SIGTERM)
    return True

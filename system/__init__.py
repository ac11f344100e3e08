"""The composition: the gridfleet command, how the system is assembled, run and fed."""

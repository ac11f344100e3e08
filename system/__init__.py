"""The composition: the gridfleet command, how the system is assembled and run."""

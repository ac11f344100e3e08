"""The chaos soak (`gridfleet bench soak`): faults injected while jobs flow, safety checked."""

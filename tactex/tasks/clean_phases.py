"""Phase codes of the cleaning state machine (TEC §V-A3), recorded in its series and read by its report."""

CLEAN_PHASES = {"move": 0, "capture": 1, "approach": 2, "explore": 3, "retract": 4}

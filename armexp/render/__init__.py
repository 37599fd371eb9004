"""Pictures of stored episodes that need no simulation, environment or agent code."""

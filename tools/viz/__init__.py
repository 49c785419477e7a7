"""A run as roboticists see it: Foxglove messages of run-log records, MCAP files, a live view, animations."""

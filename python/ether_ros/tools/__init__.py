"""Tools around the bus: real-time host check/setup, experiments, recording, plots, live view."""

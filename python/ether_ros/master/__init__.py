"""The master: bring a bus to OP through the engine's datagram service, then run it cyclically."""

"""Simulator front: build a virtual EtherCAT network from a bus config and run it."""

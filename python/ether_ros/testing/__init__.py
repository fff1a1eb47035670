"""Helpers for tests and benchmarks: veth pairs, network namespaces, subprocess management."""

"""Bus configuration (YAML) and device descriptions (ESI XML), parsed into typed models."""

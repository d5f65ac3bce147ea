"""What people and tools see of the running daemon: structured logs (secrets
redacted) and Prometheus metrics.

- `telemetry`  logging (structlog), metrics, the registry of secrets
"""

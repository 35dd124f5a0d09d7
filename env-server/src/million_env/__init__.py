"""MILLION environment server: Gymnasium and Meta-World v3 environments over gRPC."""

__version__ = "0.1.0"

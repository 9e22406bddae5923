"""Metrics (ATE/RPE, evo-compatible), the run harness, sweeps, gates, reports, CLI."""

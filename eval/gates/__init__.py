"""Verdicts on rows: robustness budgets for CI (per run, over seeds, against a baseline)
and the paired comparison of two result sets."""

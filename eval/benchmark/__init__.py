"""Frozen, named benchmarks: a shipped set of sequences (keyed to the byte), one tracker
configuration scored on them with repeats where it is not deterministic, a results file
that anyone can recompute, and the papers' tables from it against any baseline."""

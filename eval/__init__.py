"""Evaluation, in the order of the pipeline: ``metrics`` (numbers from trajectories and
rows) -> ``trackers`` (frames into trajectories) -> ``run`` (one sequence, one detector, one
tracker) -> ``detection`` (detector tools) -> ``sweep`` (many runs, a database) -> ``gates``
(verdicts on rows) -> ``report`` (pages) -> ``cli`` (the command line); ``pytest_plugin``
serves the same to pytest. Each imports only those before it (tests/test_architecture.py)."""

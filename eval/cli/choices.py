"""The command line's choices and defaults that live in heavy modules, named here so that
building the parsers (``depotbench --help``) imports no NumPy or SciPy: 0.1 s against 0.5 s.
``tests/test_cli_conventions.py`` holds each equal to its source."""

from __future__ import annotations

STRATEGIES = ("none", "box_rule", "prior_flow", "box_epipolar_flow", "mask")
"""``depotbench.eval.run.harness.STRATEGY_CHOICES``."""
ALIGNMENTS = ("none", "se3", "sim3")
"""``depotbench.eval.metrics.alignment.Alignment``."""
DELTA_UNITS = ("frames", "m")
"""``depotbench.eval.metrics.accuracy.DeltaUnit``."""
MAX_DIFF_S = 0.02
"""``depotbench.eval.metrics.trajectory.DEFAULT_MAX_DIFF_S``: TUM's association window."""
VOCABULARY_DEFAULTS = {"branching": 10, "levels": 5, "frames": 150, "seed": 101}
"""``depotbench.eval.trackers.vocabulary.VocabularySpec``'s defaults."""
TRAINING_SCENES = (
    "dog_and_cat_roaming",
    "pig_pen",
    "chair_pushing",
    "robot_aisle_patrol",
    "crowd",
    "sitting_halfsphere",
)
"""``depotbench.eval.trackers.vocabulary.TRAINING_SCENES``."""

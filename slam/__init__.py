"""RGB-D SLAM: features, tracking, rejection strategies, pose estimation, mapping.

Consumes frames and ``depotbench.detectors.detection.Detection`` only, so it runs unchanged
on real TUM sequences with any detector.
"""

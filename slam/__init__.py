"""RGB-D SLAM in ORB-SLAM2's shape, split along ORB-SLAM's parts.

From the bottom: types, settings (config), geometry and ORB features; the map, the matcher
(ORB-SLAM's ORBmatcher), the optimiser (optimize, bundle), pose solving and the rejection
strategies; local mapping and relocalisation; tracking (the per-frame state machine); and
``system.Slam``, the facade a run drives. It consumes frames, the camera
(``depotbench.core.camera``) and ``depotbench.detectors.detection.Detection`` only, so it
runs unchanged on real TUM sequences with any detector.
"""

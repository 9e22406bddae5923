"""Trackers behind one interface: the built-in pipeline, ORB-SLAM3 and external programs."""

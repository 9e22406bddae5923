"""Detector tools beside the SLAM pipeline: how a detector sees the bench's scenes
(precision, recall, AP50) and the generated frames as a YOLO/COCO training set."""

"""Detectors behind one interface: ground-truth boxes (with fault injection) and
an ONNX Runtime YOLO detector. All produce ``depotbench.detectors.detection.Detection``."""

"""Insulator detection: YOLO ONNX runtime (detector), its pre/post-processing, evaluation, training tool."""

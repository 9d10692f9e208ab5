"""Detection models built for tests: ONNX files that output chosen rows whatever the image."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def hostile_model(path: Path, rows: list[tuple[float, ...]]) -> Path:
    """An ONNX file in Ultralytics' YOLO detection export format that outputs ``rows`` for any image."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    table = np.array(rows, dtype=np.float32).T[None]  # (1, 5, N)
    nodes = [
        # 0 * mean(image) keeps the input in the graph (an unused input is legal but unusual).
        helper.make_node("ReduceMean", ["images"], ["mean"], axes=[1, 2, 3], keepdims=0),
        helper.make_node("Mul", ["mean", "zero"], ["nothing"]),
        helper.make_node("Add", ["table", "nothing"], ["output0"]),
    ]
    graph = helper.make_graph(
        nodes, "hostile_yolo",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, ["batch", 3, "height", "width"])],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, [1, 5, len(rows)])],
        initializer=[numpy_helper.from_array(table, "table"),
                     numpy_helper.from_array(np.zeros(1, np.float32), "zero")])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    for key, value in {"task": "detect", "names": "{0: 'insulator'}", "imgsz": "[320, 320]", "stride": "32"}.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path

"""Insulator detector: an Ultralytics YOLO detection export run by onnxruntime.

Loads any YOLO11/YOLOv8 detection ONNX export (output ``[1, 4 + nc, N]``,
sigmoid class scores, no objectness), static or dynamic input, and reads the
class names and input size from the metadata Ultralytics writes into the file.
Pre-processing is Ultralytics' (letterbox, BGR->RGB, /255, NCHW float32),
post-processing its NMS, so results match ``YOLO(model).predict`` (see
tests/test_detection_parity.py). Output boxes are in pixels of the image given,
x1, y1, x2, y2, float64, ready for ``ir.points_in_boxes``.
"""

from __future__ import annotations

import ast
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort

from insulator_rs.detection.letterbox import LetterboxGeometry, letterbox, to_network_input
from insulator_rs.detection.postprocess import RawDetections, suppress, yolo_candidates
from insulator_rs.detection.sanitize import DroppedDetections, clip_to_image, drop_invalid
from insulator_rs.exceptions import ModelError

PREFERRED_PROVIDERS = ("TensorrtExecutionProvider", "CUDAExecutionProvider", "CPUExecutionProvider")
DEFAULT_IMGSZ = 640  # Ultralytics' default when a dynamic model carries no imgsz
ONNX_MAGIC_MIN_BYTES = 64  # smaller files cannot hold a graph
MAX_BATCH = 16  # images a dynamic-batch network takes in one run (memory stays ~ 16 frames' input)


@dataclass(frozen=True)
class Detections:
    """Detections in one image, in pixels of that image (x right, y down)."""

    boxes: np.ndarray  # (M, 4) float64 x1, y1, x2, y2
    scores: np.ndarray  # (M,) float64 in [0, 1]
    class_ids: np.ndarray  # (M,) int64
    names: dict[int, str]
    dropped: DroppedDetections = DroppedDetections()  # what the sanitiser removed (sanitize.py)

    def __len__(self) -> int:
        return int(self.boxes.shape[0])

    @property
    def labels(self) -> list[str]:
        """Class name of each detection."""
        return [self.names.get(int(c), str(int(c))) for c in self.class_ids]


def select_providers(available: Sequence[str] | None = None) -> list[str]:
    """TensorRT, then CUDA, then CPU: those of them that onnxruntime has installed."""
    have = set(ort.get_available_providers() if available is None else available)
    chosen = [p for p in PREFERRED_PROVIDERS if p in have]
    if not chosen:
        raise RuntimeError(f"onnxruntime offers none of {PREFERRED_PROVIDERS}; it has {sorted(have)}")
    return chosen


def _with_options(providers: Sequence[str], model: Path) -> list[str | tuple[str, dict[str, str]]]:
    """The providers as onnxruntime takes them: TensorRT with its engine cache and FP16
    (jetson_export.tensorrt_provider_options), the others as named."""
    from insulator_rs.detection.jetson_export import tensorrt_provider_options

    return [(p, tensorrt_provider_options(model)) if p == "TensorrtExecutionProvider" else p for p in providers]


def _parse_meta(value: str, key: str, path: Path) -> object:
    try:
        return ast.literal_eval(value)
    except (ValueError, SyntaxError) as exc:
        raise ModelError(f"model {path}: not a YOLO detection export (metadata {key!r} unreadable: {value!r})") from exc


def as_bgr_uint8(image: np.ndarray, *, name: str = "image") -> np.ndarray:
    """Check an image and convert gray (H, W) / (H, W, 1) and BGRA (H, W, 4) to BGR (H, W, 3).

    Raises TypeError for a non-array or a dtype other than uint8, and
    ValueError for an empty image or a channel count other than 1, 3 or 4.
    """
    if not isinstance(image, np.ndarray):
        raise TypeError(f"{name} must be a numpy array (H, W, 3) uint8 BGR, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise TypeError(f"{name} must have dtype uint8 (BGR 0-255), got {image.dtype}")
    if image.ndim == 2:
        image = image[:, :, None]
    if image.ndim != 3:
        raise ValueError(f"{name} must be (H, W), (H, W, 1), (H, W, 3) or (H, W, 4), got shape {image.shape}")
    if image.shape[0] == 0 or image.shape[1] == 0:
        raise ValueError(f"{name} is empty: shape {image.shape}")
    channels = image.shape[2]
    if channels == 3:
        return image
    if channels == 1:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if channels == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    raise ValueError(f"{name} must have 1, 3 or 4 channels, got {channels} (shape {image.shape})")


class Detector:
    """YOLO detection model on onnxruntime.

    Args:
        model: path of the ONNX export.
        conf: keep detections whose best class score is above this.
        iou: NMS IoU threshold (same-class boxes overlapping more are dropped).
        max_det: most detections per image.
        imgsz: network input size (square int or (h, w)); default from the
            model's metadata, else its static input shape, else 640.
        providers: onnxruntime providers; default TensorRT > CUDA > CPU of those installed.
        threads: intra-op threads for the CPU provider (None: onnxruntime's default).
        warmup: run one blank image at construction so the first real frame is not slow.
        agnostic: class-agnostic NMS.
        rect: pad only to the next multiple of the stride (needs a dynamic input);
            default: on for dynamic models, as Ultralytics' predict does.
        spinning: the CPU provider's threads spin-wait for work between runs (onnxruntime's
            default: the lowest latency on an otherwise idle CPU). Off where other threads need
            the cores: spinning threads took the core a replay's loop ran on beside its
            read-ahead, and the two ran no faster together than one after the other.

    Raises:
        ModelError: the file is missing, truncated/not ONNX, or not a YOLO detection export.
    """

    def __init__(
        self,
        model: str | os.PathLike[str],
        *,
        conf: float = 0.25,
        iou: float = 0.7,
        max_det: int = 300,
        imgsz: int | tuple[int, int] | None = None,
        providers: Sequence[str] | None = None,
        threads: int | None = None,
        warmup: bool = True,
        agnostic: bool = False,
        rect: bool | None = None,
        spinning: bool = True,
    ) -> None:
        if not 0.0 <= conf <= 1.0:
            raise ValueError(f"conf must be in [0, 1], got {conf}")
        if not 0.0 <= iou <= 1.0:
            raise ValueError(f"iou must be in [0, 1], got {iou}")
        if max_det < 1:
            raise ValueError(f"max_det must be >= 1, got {max_det}")
        if threads is not None and threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        self.path = Path(model)
        self.conf, self.iou, self.max_det, self.agnostic = conf, iou, max_det, agnostic
        self.session = self._open_session(self.path, providers, threads, spinning)
        self.providers = self.session.get_providers()
        inp = self.session.get_inputs()
        outs = self.session.get_outputs()
        if len(inp) != 1 or len(inp[0].shape) != 4:
            raise ModelError(f"model {self.path}: not a YOLO detection export (expects one NCHW input, "
                             f"has {[(i.name, i.shape) for i in inp]})")
        if len(outs) != 1 or len(outs[0].shape) != 3:
            raise ModelError(f"model {self.path}: not a YOLO detection export (expects one [1, 4+nc, N] output, "
                             f"has {[(o.name, o.shape) for o in outs]})")
        if isinstance(inp[0].shape[1], int) and inp[0].shape[1] != 3:
            raise ModelError(f"model {self.path}: not a YOLO detection export (input has {inp[0].shape[1]} channels)")
        self.input_name = inp[0].name
        meta = self.session.get_modelmeta().custom_metadata_map
        task = meta.get("task")
        if task is not None and task != "detect":
            raise ModelError(f"model {self.path}: not a YOLO detection export (task {task!r})")
        if meta.get("end2end") == "True":
            raise ModelError(f"model {self.path}: end-to-end (NMS-free) head not supported; export with end2end=False")
        self.names = self._read_names(meta, outs[0].shape)
        self.dynamic = not all(isinstance(d, int) for d in inp[0].shape[2:])
        # most images one network run takes (an export with a fixed batch of 1: one at a time)
        self.max_batch = int(inp[0].shape[0]) if isinstance(inp[0].shape[0], int) else MAX_BATCH
        self.imgsz = self._input_size(imgsz, meta, inp[0].shape)
        if rect and not self.dynamic:
            raise ValueError(f"rect=True needs a model with a dynamic input; {self.path} is fixed at {self.imgsz}")
        self.rect = self.dynamic if rect is None else rect
        self.stride = int(_parse_meta(meta["stride"], "stride", self.path)) if "stride" in meta else 32  # type: ignore[call-overload]
        self.metadata = dict(meta)
        if warmup:
            self.warmup()

    @classmethod
    def from_name(cls, name: str, **kwargs: object) -> Detector:
        """A model shipped with the package (``insulator_rs.models``), e.g. ``"insulator-real"``."""
        from insulator_rs.models import model_path

        return cls(model_path(name), **kwargs)  # type: ignore[arg-type]

    @staticmethod
    def _open_session(path: Path, providers: Sequence[str] | None, threads: int | None,
                      spinning: bool = True) -> ort.InferenceSession:
        if not path.is_file():
            raise ModelError(f"model {path}: file not found")
        if path.stat().st_size < ONNX_MAGIC_MIN_BYTES:
            raise ModelError(f"model {path}: truncated or not ONNX ({path.stat().st_size} bytes)")
        opts = ort.SessionOptions()
        if threads is not None:
            opts.intra_op_num_threads = threads
            opts.inter_op_num_threads = 1
        if not spinning:
            opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        opts.log_severity_level = 3  # TensorRT/CUDA fall-back chatter is not an error
        chosen = list(providers) if providers else select_providers()
        try:
            return ort.InferenceSession(str(path), sess_options=opts, providers=_with_options(chosen, path))
        except Exception as exc:  # onnxruntime raises its own untyped errors for bad protobufs
            raise ModelError(f"model {path}: truncated or not ONNX ({type(exc).__name__}: {exc})") from exc

    def _read_names(self, meta: dict[str, str], out_shape: Sequence[object]) -> dict[int, str]:
        channels = out_shape[1]
        names: dict[int, str] | None = None
        if "names" in meta:
            parsed = _parse_meta(meta["names"], "names", self.path)
            if not isinstance(parsed, dict) or not parsed:
                raise ModelError(f"model {self.path}: not a YOLO detection export (names {meta['names']!r})")
            names = {int(k): str(v) for k, v in parsed.items()}
        if isinstance(channels, int):
            if channels < 5:
                raise ModelError(f"model {self.path}: not a YOLO detection export (output has {channels} channels,"
                                 " needs 4 box + at least 1 class)")
            if names is None:
                names = {i: f"class{i}" for i in range(channels - 4)}
            elif len(names) != channels - 4:
                raise ModelError(f"model {self.path}: not a YOLO detection export ({len(names)} names in metadata "
                                 f"but {channels - 4} class channels; segmentation/pose heads are not supported)")
        if names is None:
            raise ModelError(f"model {self.path}: not a YOLO detection export (no class names and no static class count)")
        return names

    def _input_size(self, imgsz: int | tuple[int, int] | None, meta: dict[str, str],
                    in_shape: Sequence[object]) -> tuple[int, int]:
        if not self.dynamic:
            static = (int(in_shape[2]), int(in_shape[3]))  # type: ignore[call-overload]
            if imgsz is not None and _as_hw(imgsz) != static:
                raise ValueError(f"imgsz {imgsz} differs from the model's fixed input {static}")
            return static
        if imgsz is not None:
            return _as_hw(imgsz)
        if "imgsz" in meta:
            parsed = _parse_meta(meta["imgsz"], "imgsz", self.path)
            return _as_hw(parsed)  # type: ignore[arg-type]
        return (DEFAULT_IMGSZ, DEFAULT_IMGSZ)

    def warmup(self) -> None:
        """Run one gray frame through the network (allocations, provider kernels)."""
        h, w = self.imgsz
        self.session.run(None, {self.input_name: np.full((1, 3, h, w), 114 / 255, dtype=np.float32)})

    def raw(self, image: np.ndarray) -> tuple[np.ndarray, LetterboxGeometry]:
        """Network output ``[1, 4 + nc, N]`` for one image, and its letterbox geometry."""
        bgr = as_bgr_uint8(image)
        padded, geo = letterbox(bgr, self.imgsz, auto=self.rect, stride=self.stride)
        out = self.session.run(None, {self.input_name: to_network_input(padded)})[0]
        return out, geo

    def detect(self, image: np.ndarray) -> Detections:
        """Detect objects in one BGR uint8 image (gray and BGRA are converted)."""
        out, geo = self.raw(image)
        return self.decode(out, geo)

    def detect_batch(self, images: Sequence[np.ndarray]) -> list[Detections]:
        """:meth:`detect` of each image, the network run once for each run of consecutive images
        whose letterboxed inputs share a shape (a stream's frames: one run), at most
        :attr:`max_batch` at a time. Each image's detections are :meth:`detect`'s up to the
        float rounding of a batched convolution."""
        prepared = [letterbox(as_bgr_uint8(image, name=f"images[{i}]"), self.imgsz, auto=self.rect,
                              stride=self.stride) for i, image in enumerate(images)]
        results: list[Detections] = []
        start = 0
        while start < len(prepared):
            shape = prepared[start][0].shape
            end = start + 1
            while end < len(prepared) and end - start < self.max_batch and prepared[end][0].shape == shape:
                end += 1
            batch = np.concatenate([to_network_input(padded) for padded, _ in prepared[start:end]])
            out = self.session.run(None, {self.input_name: batch})[0]
            results.extend(self.decode(out[k - start:k - start + 1], prepared[k][1]) for k in range(start, end))
            start = end
        return results

    def decode(self, out: np.ndarray, geo: LetterboxGeometry) -> Detections:
        """One image's network output ``[1, 4 + nc, N]`` (:meth:`raw`) -> its detections in its own
        pixels, at this detector's ``conf``, ``iou`` and ``max_det``: one network pass decoded at
        several thresholds is what :meth:`detect` gives at each."""
        cands = yolo_candidates(out, conf=self.conf)
        # The detector's edge (sanitize.py): NaN/Inf/inverted boxes and bad scores go before NMS,
        # where they could survive or suppress a valid box; then NMS as Ultralytics does it.
        valid, dropped = drop_invalid(cands.boxes, cands.scores)
        cands = RawDetections(cands.boxes[valid], cands.scores[valid], cands.class_ids[valid])
        kept = suppress(cands, iou=self.iou, max_det=self.max_det, agnostic=self.agnostic)
        with np.errstate(over="ignore"):
            mapped = geo.to_original(kept.boxes, clip=False)
        h, w = geo.orig_hw
        boxes, inside, small = clip_to_image(mapped, w, h)
        dropped = dropped + small
        kept = RawDetections(boxes, kept.scores[inside].astype(np.float64), kept.class_ids[inside])
        return Detections(kept.boxes, kept.scores, kept.class_ids, self.names, dropped)

    __call__ = detect

    def __repr__(self) -> str:
        return (f"Detector({str(self.path)!r}, imgsz={self.imgsz}, names={self.names}, conf={self.conf}, "
                f"iou={self.iou}, rect={self.rect}, providers={self.providers})")


def _as_hw(imgsz: int | Sequence[int]) -> tuple[int, int]:
    if isinstance(imgsz, (int, np.integer)):
        hw = (int(imgsz), int(imgsz))
    else:
        vals = [int(v) for v in imgsz]
        if len(vals) == 1:
            vals = vals * 2
        if len(vals) != 2:
            raise ValueError(f"imgsz must be an int or (h, w), got {imgsz}")
        hw = (vals[0], vals[1])
    if min(hw) < 32 or hw[0] % 32 or hw[1] % 32:
        raise ValueError(f"imgsz must be positive multiples of 32 (YOLO stride), got {imgsz}")
    return hw


def open_detector(model: str, *, conf: float, iou: float = 0.7, threads: int | None = None,
                  imgsz: int | None = None, spinning: bool = True) -> Detector:
    """A detector from a shipped model name or an ONNX path (``imgsz``: input size, default the
    model's; ``spinning``: see :class:`Detector`)."""
    if model.endswith(".onnx") or Path(model).exists():
        return Detector(model, conf=conf, iou=iou, threads=threads, imgsz=imgsz, spinning=spinning)
    return Detector.from_name(model, conf=conf, iou=iou, threads=threads, imgsz=imgsz, spinning=spinning)

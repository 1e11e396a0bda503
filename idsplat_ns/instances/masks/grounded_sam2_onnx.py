"""Grounded-SAM-2 through ONNX Runtime: Grounding DINO boxes for the class prompts, SAM 2 masks for
the boxes, IDs kept consistent over frames by mask IoU and class (per camera; lifting merges the
cameras through shared lidar points).

Model files are the user's (nothing downloads); the expected signatures are those of the common
public exports (documented in docs/instances.md):

Grounding DINO (e.g. the official repo's ONNX export with dynamic axes):
    inputs  ``img`` float32 [1, 3, H, W] (RGB / 255, ImageNet mean/std; shorter side 800, longer at
            most 1333, or the export's fixed size), ``input_ids`` int64 [1, L], ``attention_mask``
            bool [1, L], ``position_ids`` int64 [1, L], ``token_type_ids`` int64 [1, L],
            ``text_token_mask`` bool [1, L, L]
    outputs ``logits`` float32 [1, Q, 256] (pre-sigmoid, per text token), ``boxes`` float32 [1, Q, 4]
            (cx, cy, w, h normalised to [0, 1])
SAM 2 image encoder / mask decoder (the two-file exports, e.g. ``encoder.onnx`` / ``decoder.onnx``):
    encoder inputs  ``image`` float32 [1, 3, S, S] (S = 1024: the image resized to S x S, RGB / 255,
                    ImageNet mean/std)
    encoder outputs ``high_res_feats_0``, ``high_res_feats_1``, ``image_embed``
    decoder inputs  ``image_embed``, ``high_res_feats_0``, ``high_res_feats_1``, ``point_coords``
                    float32 [1, 2, 2] (box corners in the S x S frame), ``point_labels`` float32 [1, 2]
                    (2, 3 = box corners), ``mask_input`` float32 [1, 1, S/4, S/4], ``has_mask_input``
                    float32 [1], and ``orig_im_size`` [2] where the export has it
    decoder outputs ``masks`` float32 [1, M, h, w] (logits; M candidates), ``iou_predictions`` [1, M]
The SAM 2 video predictor's memory modules have no standard ONNX export, so temporal consistency
uses mask-IoU association (:mod:`idsplat_ns.instances.masks.association`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import cv2
import numpy as np
from tqdm import tqdm

from idsplat_ns.data.images import load_rgb
from idsplat_ns.data.scene import Scene
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.masks.association import IouTracker
from idsplat_ns.instances.masks.base import PROMPT_CLASSES, InstanceMaskSet, MaskSource, write_instance_map, write_labels
from idsplat_ns.instances.masks.bert_tokenizer import WordPieceTokenizer, caption_inputs
from idsplat_ns.instances.onnx_session import model_identity, open_session
from idsplat_ns.instances.options import cli_option
from idsplat_ns.ranges import AT_LEAST_ONE, UNIT, bounded

IMAGENET_MEAN = np.array([0.485, 0.456, 0.406], np.float32)
IMAGENET_STD = np.array([0.229, 0.224, 0.225], np.float32)
DETECTOR_INPUTS = ("img", "input_ids", "attention_mask", "position_ids", "token_type_ids", "text_token_mask")
ENCODER_OUTPUTS = ("high_res_feats_0", "high_res_feats_1", "image_embed")
DECODER_INPUTS = ("image_embed", "high_res_feats_0", "high_res_feats_1", "point_coords", "point_labels", "mask_input", "has_mask_input")


@dataclass(frozen=True)
class GroundedSam2Config:
    """Model files and thresholds of the Grounded-SAM-2 mask source (Grounded-SAM-2's defaults)."""

    detector_path: Optional[Path] = None
    """Grounding DINO ONNX file."""
    tokenizer_vocab: Optional[Path] = None
    """``vocab.txt`` of bert-base-uncased (Grounding DINO's text encoder)."""
    sam2_encoder_path: Optional[Path] = None
    """SAM 2 image-encoder ONNX file."""
    sam2_decoder_path: Optional[Path] = None
    """SAM 2 mask-decoder ONNX file."""
    prompts: tuple[str, ...] = PROMPT_CLASSES
    """Class prompts (the paper's nine)."""
    box_threshold: float = bounded(0.35, UNIT)
    """A box is kept when its best token probability exceeds this."""
    text_threshold: float = bounded(0.25, UNIT)
    """A box is labelled with the prompt whose best token probability is highest, if above this."""
    nms_iou: float = bounded(0.7, UNIT)
    """Boxes overlapping a higher-scoring box by more than this IoU are dropped."""
    detector_short_side: int = 800
    """Shorter image side fed to the detector (when its input size is dynamic)."""
    detector_max_side: int = 1333
    """Longest side limit for the detector input."""
    max_text_len: int = bounded(256, AT_LEAST_ONE)
    """Token capacity of the detector's text branch."""
    min_mask_pixels: int = 50
    """Masks smaller than this are dropped."""
    track_iou: float = bounded(0.3, UNIT)
    """Minimum mask IoU between consecutive detections of one object."""
    track_max_gap: int = 3
    """Frames a track may be unseen and still continue."""
    threads: int = 0
    """ONNX Runtime intra-op threads (0: its default)."""


def _static_hw(session, name: str) -> Optional[tuple[int, int]]:
    shape = next(i.shape for i in session.get_inputs() if i.name == name)
    h, w = shape[2], shape[3]
    return (h, w) if isinstance(h, int) and isinstance(w, int) else None


def _normalise(rgb: np.ndarray, size_wh: tuple[int, int]) -> np.ndarray:  # rgb [H, W, 3] -> [1, 3, h, w]
    x = cv2.resize(rgb, size_wh, interpolation=cv2.INTER_LINEAR)
    x = (x.astype(np.float32) / 255.0 - IMAGENET_MEAN) / IMAGENET_STD
    return np.ascontiguousarray(x.transpose(2, 0, 1)[None])


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:  # a: [N, 4], b: [M, 4] xyxy -> [N, M]
    lt = np.maximum(a[:, None, :2], b[None, :, :2])
    rb = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.prod(np.clip(rb - lt, 0, None), -1)
    area_a = np.prod(a[:, 2:] - a[:, :2], 1)
    area_b = np.prod(b[:, 2:] - b[:, :2], 1)
    return inter / np.maximum(area_a[:, None] + area_b[None] - inter, 1e-9)


def nms(boxes: np.ndarray, scores: np.ndarray, iou: float) -> np.ndarray:
    """Indices kept by greedy non-maximum suppression, highest score first."""
    order, keep = np.argsort(-scores), []
    while len(order):
        i = order[0]
        keep.append(i)
        order = order[1:][box_iou(boxes[i : i + 1], boxes[order[1:]])[0] <= iou]
    return np.array(keep, int)


@dataclass
class Detection:
    box: np.ndarray  # [4] xyxy pixels of the original image
    score: float
    label: str


class GroundedSam2OnnxMasks(MaskSource):
    """Detect (Grounding DINO), segment (SAM 2), associate (mask IoU) on every frame of every camera."""

    name = "grounded_sam2"

    def __init__(self, config: GroundedSam2Config):
        self.config = config
        c = config
        for path, option in ((c.tokenizer_vocab, "tokenizer-vocab"), (c.detector_path, "detector-path"),
                             (c.sam2_encoder_path, "sam2-encoder-path"), (c.sam2_decoder_path, "sam2-decoder-path")):
            _require_file(path, cli_option(f"masks.grounded-sam2.{option}"))  # fail early, before any frame
        self._loaded = False

    def _load(self) -> None:
        """Open the three sessions and the tokenizer (on first use: cached runs never load them)."""
        if self._loaded:
            return
        c = self.config
        self.tokenizer = WordPieceTokenizer(_required(c.tokenizer_vocab, cli_option("masks.grounded-sam2.tokenizer-vocab")))
        self.detector = open_session(c.detector_path, cli_option("masks.grounded-sam2.detector-path"), c.threads)
        self.encoder = open_session(c.sam2_encoder_path, cli_option("masks.grounded-sam2.sam2-encoder-path"), c.threads)
        self.decoder = open_session(c.sam2_decoder_path, cli_option("masks.grounded-sam2.sam2-decoder-path"), c.threads)
        _check_names(self.detector, DETECTOR_INPUTS, c.detector_path, "inputs")
        _check_names(self.detector, ("logits", "boxes"), c.detector_path, "outputs")
        _check_names(self.encoder, ENCODER_OUTPUTS, c.sam2_encoder_path, "outputs")
        _check_names(self.decoder, DECODER_INPUTS, c.sam2_decoder_path, "inputs")
        self.encoder_input = self.encoder.get_inputs()[0].name
        hw = _static_hw(self.encoder, self.encoder_input)
        self.sam_size = hw if hw else (1024, 1024)
        self.text = caption_inputs(self.tokenizer, c.prompts, c.max_text_len)
        self._loaded = True

    def cache_key(self) -> dict:
        c = self.config
        return {"source": self.name, "detector": model_identity(c.detector_path), "vocab": model_identity(c.tokenizer_vocab),
                "encoder": model_identity(c.sam2_encoder_path), "decoder": model_identity(c.sam2_decoder_path),
                "prompts": list(c.prompts), "box": c.box_threshold, "text": c.text_threshold, "nms": c.nms_iou,
                "short": c.detector_short_side, "max": c.detector_max_side, "min_px": c.min_mask_pixels,
                "track_iou": c.track_iou, "gap": c.track_max_gap}

    def detect(self, rgb: np.ndarray) -> list[Detection]:
        """Boxes and classes of the prompts in one image."""
        self._load()
        c, H, W = self.config, rgb.shape[0], rgb.shape[1]
        fixed = _static_hw(self.detector, "img")
        if fixed:
            h, w = fixed
        else:
            s = c.detector_short_side / min(H, W)
            s = min(s, c.detector_max_side / max(H, W))
            h, w = int(round(H * s)), int(round(W * s))
        t = self.text
        logits, boxes = self.detector.run(["logits", "boxes"], {
            "img": _normalise(rgb, (w, h)), "input_ids": t.input_ids, "attention_mask": t.attention_mask,
            "position_ids": t.position_ids, "token_type_ids": t.token_type_ids, "text_token_mask": t.text_token_mask})
        prob = 1.0 / (1.0 + np.exp(-np.asarray(logits[0], np.float64)))  # [Q, 256]
        L = t.input_ids.shape[1]
        keep = prob[:, :L].max(1) > c.box_threshold
        prompt_scores = np.stack([prob[:, tok].max(1) for tok in t.prompt_tokens], 1)  # [Q, P]
        best = np.argmax(prompt_scores, 1)
        keep &= prompt_scores[np.arange(len(best)), best] > c.text_threshold
        if not keep.any():
            return []
        cxcywh = np.asarray(boxes[0], np.float64)[keep] * [W, H, W, H]
        xyxy = np.concatenate([cxcywh[:, :2] - cxcywh[:, 2:] / 2, cxcywh[:, :2] + cxcywh[:, 2:] / 2], 1)
        xyxy = np.clip(xyxy, 0, [W, H, W, H])
        scores = prob[keep, :L].max(1)
        labels = [c.prompts[i] for i in best[keep]]
        order = nms(xyxy, scores, c.nms_iou)
        return [Detection(xyxy[i], float(scores[i]), labels[i]) for i in order]

    def segment(self, rgb: np.ndarray, boxes: list[np.ndarray]) -> list[np.ndarray]:
        """One [H, W] bool mask per box (the candidate with the highest predicted IoU)."""
        if not boxes:
            return []
        self._load()
        H, W = rgb.shape[:2]
        sh, sw = self.sam_size
        feats = self.encoder.run(list(ENCODER_OUTPUTS), {self.encoder_input: _normalise(rgb, (sw, sh))})
        feeds = dict(zip(ENCODER_OUTPUTS, feats))
        dec_inputs = {i.name: i for i in self.decoder.get_inputs()}
        feeds["mask_input"] = np.zeros((1, 1, sh // 4, sw // 4), np.float32)
        feeds["has_mask_input"] = np.zeros(1, np.float32)
        if "orig_im_size" in dec_inputs:
            dtype = np.int64 if "int64" in dec_inputs["orig_im_size"].type else np.int32
            feeds["orig_im_size"] = np.array([H, W], dtype)
        out_names = [o.name for o in self.decoder.get_outputs()]
        masks = []
        for box in boxes:
            corners = np.array([[box[0] * sw / W, box[1] * sh / H], [box[2] * sw / W, box[3] * sh / H]], np.float32)
            feeds["point_coords"] = corners[None]
            feeds["point_labels"] = np.array([[2, 3]], np.float32)
            res = dict(zip(out_names, self.decoder.run(None, feeds)))
            cand = np.asarray(res["masks"])[0]  # [M, h, w] logits
            pick = int(np.argmax(np.asarray(res["iou_predictions"])[0])) if "iou_predictions" in res else 0
            logit = cv2.resize(cand[pick].astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR)
            masks.append(logit > 0)
        return masks

    def generate(self, scene: Scene, out_dir: Path, progress: bool = True) -> InstanceMaskSet:
        out_dir.mkdir(parents=True, exist_ok=True)
        labels: dict[int, str] = {}
        next_id = 1
        bar = tqdm(total=len(scene.images), desc="grounded-sam2 masks", disable=not progress)
        for camera in scene.camera_names:
            tracker = IouTracker(self.config.track_iou, self.config.track_max_gap, next_id)
            for image in sorted(scene.images_of(camera), key=lambda im: im.frame_index):
                rgb = load_rgb(image)
                dets = self.detect(rgb)
                masks = self.segment(rgb, [d.box for d in dets])
                kept = [(d, m) for d, m in zip(dets, masks) if m.sum() >= self.config.min_mask_pixels]
                ids = tracker.update(image.frame_index, [m for _, m in kept], [d.label for d, _ in kept])
                id_map = np.zeros(rgb.shape[:2], np.uint16)
                for (d, m), k in sorted(zip(kept, ids), key=lambda x: x[0][0].score):  # best score painted last
                    id_map[m] = k
                    labels[k] = d.label
                write_instance_map(out_dir / camera / f"{image.frame_index:02d}.png", id_map)
                bar.update(1)
            next_id = tracker.next_id
        bar.close()
        write_labels(out_dir, labels)
        return InstanceMaskSet(out_dir, labels, self.name)


def _require_file(path: Optional[Path], option: str) -> Path:
    """The path, or a one-line error naming the option when it is unset or missing."""
    path = _required(path, option)
    if not path.is_file():
        raise IDSplatError(f"{path}: file not found; export it as described in docs/instances.md and pass it with {option}")
    return path


def _required(path: Optional[Path], option: str) -> Path:
    if path is None:
        raise IDSplatError(f"{option} is not set; Grounded-SAM-2 masks need it (or use {cli_option('masks.kind')} precomputed)")
    return Path(path)


def _check_names(session, expected: tuple[str, ...], path, what: str) -> None:
    have = {i.name for i in (session.get_inputs() if what == "inputs" else session.get_outputs())}
    missing = [n for n in expected if n not in have]
    if missing:
        raise IDSplatError(f"{path}: the model lacks {what} {missing} (has {sorted(have)}); export it with the names in docs/instances.md")

"""Grounded-SAM-2 and DINOv3 through ONNX Runtime, with tiny models built here that have the input
and output names of the common public exports; WordPiece tokenisation; IoU association."""

from __future__ import annotations

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from idsplat_ns.data.camera import CameraImage, Intrinsics
from idsplat_ns.data.lidar import LidarSweep
from idsplat_ns.data.scene import Scene
from idsplat_ns.errors import IDSplatError
from idsplat_ns.instances.features.dinov3_onnx import IMAGENET_MEAN, IMAGENET_STD, Dinov3Config, Dinov3OnnxFeatures
from idsplat_ns.instances.masks.association import IouTracker
from idsplat_ns.instances.masks.bert_tokenizer import WordPieceTokenizer, caption_inputs
from idsplat_ns.instances.masks.grounded_sam2_onnx import GroundedSam2Config, GroundedSam2OnnxMasks, nms

VOCAB = ["[PAD]", "[UNK]", "[CLS]", "[SEP]", ".", "?", "car", "truck", "van", "bus", "train", "human", "cycl",
         "##ist", "bicycle", "pedestrian"]
BOX = np.array([0.45, 0.5, 0.4, 0.4])  # cx, cy, w, h (normalised) of the fake detection
SAM = 64  # the fake SAM 2 encoder's input size


def _const(name, arr):
    return numpy_helper.from_array(np.asarray(arr), name)


def _save(graph, path):
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def build_detector(path):
    """Grounding-DINO-like: constant queries; query 0 is a 'truck' box, query 1 a weaker duplicate."""
    Q = 4
    logits = np.full((1, Q, 256), -8.0, np.float32)
    logits[0, 0, 3] = 3.0  # token 3 = "truck" in "[CLS] car . truck . ..."
    logits[0, 1, 3] = 1.0
    logits[0, 2, 1] = -2.0  # below the box threshold
    boxes = np.tile(BOX, (1, Q, 1)).astype(np.float32)
    boxes[0, 1, :2] += 0.01
    inputs = [
        helper.make_tensor_value_info("img", TensorProto.FLOAT, [1, 3, "h", "w"]),
        helper.make_tensor_value_info("input_ids", TensorProto.INT64, [1, "L"]),
        helper.make_tensor_value_info("attention_mask", TensorProto.BOOL, [1, "L"]),
        helper.make_tensor_value_info("position_ids", TensorProto.INT64, [1, "L"]),
        helper.make_tensor_value_info("token_type_ids", TensorProto.INT64, [1, "L"]),
        helper.make_tensor_value_info("text_token_mask", TensorProto.BOOL, [1, "L", "L"]),
    ]
    outputs = [helper.make_tensor_value_info("logits", TensorProto.FLOAT, [1, Q, 256]),
               helper.make_tensor_value_info("boxes", TensorProto.FLOAT, [1, Q, 4])]
    nodes = [
        helper.make_node("ReduceMean", ["img"], ["m"], keepdims=0),
        helper.make_node("Mul", ["m", "zero"], ["z"]),
        helper.make_node("Add", ["logits_c", "z"], ["logits"]),
        helper.make_node("Add", ["boxes_c", "z"], ["boxes"]),
    ]
    init = [_const("zero", np.float32(0)), _const("logits_c", logits), _const("boxes_c", boxes)]
    return _save(helper.make_graph(nodes, "gdino", inputs, outputs, init), path)


def build_sam2(enc_path, dec_path):
    """SAM-2-like encoder (average pools) and a decoder whose second candidate is the box prompt."""
    enc_nodes = [
        helper.make_node("AveragePool", ["image"], ["high_res_feats_0"], kernel_shape=[4, 4], strides=[4, 4]),
        helper.make_node("AveragePool", ["image"], ["high_res_feats_1"], kernel_shape=[8, 8], strides=[8, 8]),
        helper.make_node("AveragePool", ["image"], ["image_embed"], kernel_shape=[16, 16], strides=[16, 16]),
    ]
    enc = helper.make_graph(
        enc_nodes, "sam2_enc", [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, SAM, SAM])],
        [helper.make_tensor_value_info(n, TensorProto.FLOAT, s) for n, s in
         (("high_res_feats_0", [1, 3, 16, 16]), ("high_res_feats_1", [1, 3, 8, 8]), ("image_embed", [1, 3, 4, 4]))])
    _save(enc, enc_path)
    ys, xs = np.mgrid[0:SAM, 0:SAM].astype(np.float32) + 0.5
    names = ["image_embed", "high_res_feats_0", "high_res_feats_1", "point_coords", "point_labels", "mask_input", "has_mask_input"]
    shapes = [[1, 3, 4, 4], [1, 3, 16, 16], [1, 3, 8, 8], [1, "N", 2], [1, "N"], [1, 1, 16, 16], [1]]
    inputs = [helper.make_tensor_value_info(n, TensorProto.FLOAT, s) for n, s in zip(names, shapes)]
    nodes = []

    def coord(name, c, k):  # point_coords[0, c, k] as a [1, 1, 1] tensor
        nodes.append(helper.make_node("Slice", ["point_coords", f"s{c}{k}", f"e{c}{k}", "axes"], [name]))

    init = [_const("X", xs[None, None]), _const("Y", ys[None, None]), _const("axes", np.array([1, 2], np.int64)),
            _const("neg", np.full((1, 1, SAM, SAM), -10.0, np.float32)), _const("twenty", np.float32(20)),
            _const("ten", np.float32(10)), _const("iou_c", np.array([[0.2, 0.9, 0.3]], np.float32))]
    for c in (0, 1):
        for k in (0, 1):
            init += [_const(f"s{c}{k}", np.array([c, k], np.int64)), _const(f"e{c}{k}", np.array([c + 1, k + 1], np.int64))]
            coord(f"p{c}{k}", c, k)
    nodes += [
        helper.make_node("GreaterOrEqual", ["X", "p00"], ["a"]), helper.make_node("LessOrEqual", ["X", "p10"], ["b"]),
        helper.make_node("GreaterOrEqual", ["Y", "p01"], ["c"]), helper.make_node("LessOrEqual", ["Y", "p11"], ["d"]),
        helper.make_node("And", ["a", "b"], ["ab"]), helper.make_node("And", ["c", "d"], ["cd"]),
        helper.make_node("And", ["ab", "cd"], ["inside"]), helper.make_node("Cast", ["inside"], ["fi"], to=TensorProto.FLOAT),
        helper.make_node("Mul", ["fi", "twenty"], ["f20"]), helper.make_node("Sub", ["f20", "ten"], ["boxmask"]),
        helper.make_node("Concat", ["neg", "boxmask", "neg"], ["masks"], axis=1),
        helper.make_node("Identity", ["iou_c"], ["iou_predictions"]),
    ]
    dec = helper.make_graph(nodes, "sam2_dec", inputs, [helper.make_tensor_value_info("masks", TensorProto.FLOAT, [1, 3, SAM, SAM]),
                                                        helper.make_tensor_value_info("iou_predictions", TensorProto.FLOAT, [1, 3])], init)
    _save(dec, dec_path)


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    d = tmp_path_factory.mktemp("onnx")
    (d / "vocab.txt").write_text("\n".join(VOCAB) + "\n")
    build_detector(d / "gdino.onnx")
    build_sam2(d / "sam2_encoder.onnx", d / "sam2_decoder.onnx")
    return GroundedSam2Config(detector_path=d / "gdino.onnx", tokenizer_vocab=d / "vocab.txt",
                              sam2_encoder_path=d / "sam2_encoder.onnx", sam2_decoder_path=d / "sam2_decoder.onnx")


def _tiny_scene(num_frames=2, W=160, H=120) -> Scene:
    rng = np.random.default_rng(0)
    K = Intrinsics(100.0, 100.0, W / 2, H / 2, W, H)
    images = [CameraImage("front_camera", f, 0.1 * f, 0.1 * f, np.eye(4), K, image=rng.integers(0, 255, (H, W, 3)).astype(np.uint8))
              for f in range(num_frames)]
    sweep = LidarSweep(0, 0.0, 0.0, np.eye(4), np.zeros((1, 3)), np.array([[0, 0, 1.0]]), np.ones(1), np.zeros(1, np.float32),
                       np.zeros(1), np.ones(1, bool), np.zeros(1, np.int16))
    return Scene("tiny", "synthetic", None, np.arange(num_frames), 0.1 * np.arange(num_frames),
                 np.repeat(np.eye(4)[None], num_frames, 0), images, [sweep])


def test_wordpiece_and_caption_inputs(tmp_path):
    (tmp_path / "vocab.txt").write_text("\n".join(VOCAB))
    tok = WordPieceTokenizer(tmp_path / "vocab.txt")
    assert tok.tokenize("Cyclist . Truck!") == ["cycl", "##ist", ".", "truck", "[UNK]"]
    cap = caption_inputs(tok, ("car", "cyclist", "bus"))
    # [CLS] car . cycl ##ist . bus . [SEP]
    np.testing.assert_array_equal(cap.input_ids[0], [2, 6, 4, 12, 13, 4, 9, 4, 3])
    np.testing.assert_array_equal(cap.position_ids[0], [0, 0, 1, 0, 1, 2, 0, 1, 0])
    m = cap.text_token_mask[0]
    assert m[3, 4] and m[4, 5] and not m[1, 3] and not m[0, 1] and m[8, 8] and not m[7, 8]
    assert [list(t) for t in cap.prompt_tokens] == [[1], [3, 4], [6]]


def test_grounded_sam2_masks_from_tiny_models(models, tmp_path):
    scene = _tiny_scene()
    source = GroundedSam2OnnxMasks(models)
    masks = source.generate(scene, tmp_path, progress=False)
    assert masks.labels == {1: "truck"}  # the duplicate is suppressed, the weak query dropped
    W, H = 160, 120
    x0, y0 = (BOX[0] - BOX[2] / 2) * W, (BOX[1] - BOX[3] / 2) * H
    x1, y1 = (BOX[0] + BOX[2] / 2) * W, (BOX[1] + BOX[3] / 2) * H
    ref = np.zeros((H, W), bool)
    ref[int(np.ceil(y0)) : int(y1), int(np.ceil(x0)) : int(x1)] = True
    for f in (0, 1):
        ids = masks.load("front_camera", f)
        got = ids == 1
        iou = (got & ref).sum() / (got | ref).sum()
        assert iou > 0.85, iou
        assert set(np.unique(ids)) == {0, 1}  # same ID in both frames


def test_missing_model_file_names_the_option(models, tmp_path):
    from dataclasses import replace

    with pytest.raises(IDSplatError, match="sam2-decoder-path"):
        GroundedSam2OnnxMasks(replace(models, sam2_decoder_path=None))
    with pytest.raises(IDSplatError, match="nowhere.onnx"):
        GroundedSam2OnnxMasks(replace(models, detector_path=tmp_path / "nowhere.onnx"))
    with pytest.raises(IDSplatError, match="dinov3.model-path"):
        Dinov3OnnxFeatures(Dinov3Config())


def test_iou_tracker_and_nms():
    a = np.zeros((20, 20), bool)
    a[2:10, 2:10] = True
    b = np.zeros((20, 20), bool)
    b[12:18, 12:18] = True
    tr = IouTracker(min_iou=0.3, max_gap=1)
    assert tr.update(0, [a, b], ["car", "car"]) == [1, 2]
    shifted = np.roll(a, 1, axis=1)
    assert tr.update(1, [b, shifted], ["car", "car"]) == [2, 1]
    assert tr.update(2, [shifted], ["bus"]) == [3]  # another class never continues a track
    assert tr.update(5, [b], ["car"]) == [4]  # the gap is too long
    # max_gap counts the frames a track went unseen: 2 missed frames continue with max_gap 2, 3 do not.
    for missed, continued in ((2, True), (3, False)):
        tr = IouTracker(min_iou=0.3, max_gap=2)
        tr.update(0, [a], ["car"])
        assert (tr.update(missed + 1, [a], ["car"]) == [1]) is continued, missed
    boxes = np.array([[0, 0, 10, 10], [1, 1, 10, 10], [20, 20, 30, 30]], float)
    np.testing.assert_array_equal(nms(boxes, np.array([0.5, 0.9, 0.1]), 0.5), [1, 2])


def build_dinov3(path, channels=8, prefix=5, seed=0):
    rng = np.random.default_rng(seed)
    w = rng.normal(size=(channels, 3, 16, 16)).astype(np.float32) * 0.05
    b = rng.normal(size=channels).astype(np.float32)
    prefix_tokens = rng.normal(size=(1, prefix, channels)).astype(np.float32)
    nodes = [
        helper.make_node("Conv", ["pixel_values", "w", "b"], ["fmap"], kernel_shape=[16, 16], strides=[16, 16]),
        helper.make_node("Reshape", ["fmap", "shape"], ["flat"]),
        helper.make_node("Transpose", ["flat"], ["tokens"], perm=[0, 2, 1]),
        helper.make_node("Concat", ["prefix", "tokens"], ["hidden_states_7"], axis=1),
    ]
    init = [_const("w", w), _const("b", b), _const("shape", np.array([1, channels, -1], np.int64)), _const("prefix", prefix_tokens)]
    g = helper.make_graph(nodes, "dino", [helper.make_tensor_value_info("pixel_values", TensorProto.FLOAT, [1, 3, "h", "w"])],
                          [helper.make_tensor_value_info("hidden_states_7", TensorProto.FLOAT, [1, "T", channels])], init)
    _save(g, path)
    return w, b


def test_dinov3_features_sample_the_patch_grid(tmp_path):
    w, b = build_dinov3(tmp_path / "dino.onnx")
    rng = np.random.default_rng(1)
    rgb = rng.integers(0, 255, (64, 96, 3)).astype(np.uint8)
    feat = Dinov3OnnxFeatures(Dinov3Config(model_path=tmp_path / "dino.onnx", short_side=64))
    x = ((rgb.astype(np.float32) / 255 - IMAGENET_MEAN) / IMAGENET_STD).transpose(2, 0, 1)

    def patch(i, j):  # reference: the conv output of patch (i, j)
        return np.einsum("cxyz,xyz->c", w, x[:, 16 * i : 16 * i + 16, 16 * j : 16 * j + 16]) + b

    uv = np.array([[8.0, 8.0], [16 * 3 + 8, 16 * 2 + 8], [16 * 3 + 16, 16 * 2 + 8]], np.float32)
    out = feat.describe(rgb, uv)
    np.testing.assert_allclose(out[0], patch(0, 0), rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(out[1], patch(2, 3), rtol=1e-4, atol=1e-4)
    # half-way between two patch centres: bilinear upsampling gives their mean
    np.testing.assert_allclose(out[2], 0.5 * (patch(2, 3) + patch(2, 4)), rtol=1e-4, atol=1e-4)

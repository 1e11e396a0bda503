"""idsplat-export-onnx: tiny randomly initialised Grounding DINO, SAM 2 and DINOv3 models of the real
transformers architectures are saved as checkpoint folders, exported by the command, run through
the project's ONNX readers (GroundedSam2OnnxMasks, Dinov3OnnxFeatures) and compared with torch."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import torch

from idsplat_ns.instances.export_onnx import cli
from idsplat_ns.instances.features.dinov3_onnx import Dinov3Config, Dinov3OnnxFeatures, prepare_image
from idsplat_ns.instances.masks.grounded_sam2_onnx import GroundedSam2Config, GroundedSam2OnnxMasks, _normalise

DET_HW = (128, 192)  # fixed detector export size (the smallest the command accepts)
SAM_S = 128  # tiny SAM 2 image size
DINO_LAYER = 2
PROMPTS = ("car", "truck", "cyclist")


def _vocab() -> list[str]:
    """A BERT-like vocab whose special tokens sit at bert-base-uncased's IDs, which transformers'
    Grounding DINO hard-codes ([CLS] 101, [SEP] 102, '.' 1012, '?' 1029)."""
    words = [f"[unused{i}]" for i in range(1030)]
    words[0], words[100], words[101], words[102], words[1012], words[1029] = "[PAD]", "[UNK]", "[CLS]", "[SEP]", ".", "?"
    for i, w in enumerate(("car", "truck", "cy", "##cl", "##ist")):
        words[1000 + i] = w
    return words


def _tiny_models():
    from transformers import (BertConfig, DINOv3ViTConfig, DINOv3ViTModel, GroundingDinoConfig, GroundingDinoForObjectDetection,
                              Sam2Config, Sam2Model, SwinConfig)

    torch.manual_seed(0)
    gd = GroundingDinoForObjectDetection(GroundingDinoConfig(
        backbone_config=SwinConfig(embed_dim=16, depths=[1, 1, 1, 1], num_heads=[1, 1, 2, 2], window_size=4, out_indices=[2, 3, 4]),
        text_config=BertConfig(vocab_size=1030, hidden_size=32, num_hidden_layers=1, num_attention_heads=2, intermediate_size=64,
                               max_position_embeddings=64),
        num_queries=20, encoder_layers=1, decoder_layers=2, encoder_ffn_dim=64, decoder_ffn_dim=64, d_model=32,
        encoder_attention_heads=2, decoder_attention_heads=2)).eval()
    hiera = dict(model_type="sam2_hiera_det_model", hidden_size=8, image_size=[SAM_S, SAM_S], blocks_per_stage=[1, 1, 2, 1],
                 embed_dim_per_stage=[8, 16, 32, 64], num_attention_heads_per_stage=[1, 1, 2, 2], window_size_per_stage=[4, 4, 4, 4],
                 global_attention_blocks=[3], window_positional_embedding_background_size=[4, 4])
    s = SAM_S
    sam = Sam2Model(Sam2Config(
        vision_config=dict(model_type="sam2_vision_model", backbone_config=hiera, backbone_channel_list=[64, 32, 16, 8],
                           backbone_feature_sizes=[[s // 4, s // 4], [s // 8, s // 8], [s // 16, s // 16]], fpn_hidden_size=32),
        prompt_encoder_config=dict(hidden_size=32, image_size=s, patch_size=16),
        mask_decoder_config=dict(hidden_size=32, mlp_dim=64, num_attention_heads=2, iou_head_hidden_dim=32))).eval()
    dino = DINOv3ViTModel(DINOv3ViTConfig(hidden_size=32, intermediate_size=64, num_hidden_layers=3, num_attention_heads=2,
                                          num_register_tokens=4, image_size=64)).eval()
    return gd, sam, dino


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """Checkpoint folders of the tiny models, and the command's exports of them."""
    root = tmp_path_factory.mktemp("export")
    gd, sam, dino = _tiny_models()
    folders = {name: root / name for name in ("gdino", "sam2", "dinov3")}
    for name, model in zip(folders, (gd, sam, dino)):
        model.save_pretrained(folders[name])
    (folders["gdino"] / "vocab.txt").write_text("\n".join(_vocab()) + "\n")
    out = root / "onnx"
    cli.main(["--out", str(out), "--grounding-dino", str(folders["gdino"]), "--sam2", str(folders["sam2"]),
              "--dinov3", str(folders["dinov3"]), "--detector-size", *map(str, DET_HW), "--dinov3-layer", str(DINO_LAYER)])
    return {"models": (gd, sam, dino), "folders": folders, "out": out}


def _source(out) -> GroundedSam2OnnxMasks:
    source = GroundedSam2OnnxMasks(GroundedSam2Config(
        detector_path=out / "grounding_dino.onnx", tokenizer_vocab=out / "bert_vocab.txt", sam2_encoder_path=out / "sam2_encoder.onnx",
        sam2_decoder_path=out / "sam2_decoder.onnx", prompts=PROMPTS, threads=1,
        box_threshold=0.0, text_threshold=0.0))  # random weights: keep every query so detect() has work
    source._load()  # opens the sessions and checks the input/output names the project needs
    return source


def _rgb(h=50, w=80, seed=1) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 255, (h, w, 3)).astype(np.uint8)


def test_detector_matches_transformers(exported):
    gd = exported["models"][0]
    source = _source(exported["out"])
    t = source.text  # the project's tokenisation and phrase masks
    L = t.input_ids.shape[1]
    assert L != 7  # the export traced a 7-token caption: the text length is dynamic
    for seed in (1, 2, 3):  # the proposal grid once broke for some images only
        rgb = _rgb(seed=seed)
        x = _normalise(rgb, DET_HW[::-1])  # what detect() feeds for a fixed-size export
        logits, boxes = source.detector.run(["logits", "boxes"], {
            "img": x, "input_ids": t.input_ids, "attention_mask": t.attention_mask, "position_ids": t.position_ids,
            "token_type_ids": t.token_type_ids, "text_token_mask": t.text_token_mask})
        with torch.no_grad():  # transformers' own path: it derives the phrase masks from the token IDs itself
            ref = gd(pixel_values=torch.from_numpy(x), input_ids=torch.from_numpy(t.input_ids),
                     attention_mask=torch.ones(t.input_ids.shape, dtype=torch.long))
        assert logits.shape == (1, 20, 256) and boxes.shape == (1, 20, 4)
        np.testing.assert_allclose(logits[0, :, :L], ref.logits[0, :, :L].numpy(), rtol=1e-4, atol=1e-4)
        assert np.isneginf(logits[0, :, L:]).all()
        np.testing.assert_allclose(boxes, ref.pred_boxes.numpy(), rtol=1e-4, atol=1e-5)
    dets = source.detect(rgb)  # the whole post-processing runs on the real graph
    assert dets and all(d.label in PROMPTS for d in dets)
    assert all(0 <= d.box[0] <= d.box[2] <= 80 and 0 <= d.box[1] <= d.box[3] <= 50 for d in dets)


def test_sam2_matches_transformers_box_prompt(exported):
    sam = exported["models"][1]
    source = _source(exported["out"])
    rgb = _rgb(60, 90, seed=2)
    box = np.array([20.0, 10.0, 70.0, 45.0])  # xyxy in image pixels
    masks = source.segment(rgb, [box])
    x = _normalise(rgb, (SAM_S, SAM_S))
    scaled = box * [SAM_S / 90, SAM_S / 60, SAM_S / 90, SAM_S / 60]
    with torch.no_grad():  # transformers' input_boxes path (the box corners are labels 2/3 in the export)
        ref = sam(pixel_values=torch.from_numpy(x), input_boxes=torch.tensor([[scaled]], dtype=torch.float32), multimask_output=False)
    feats = dict(zip(("high_res_feats_0", "high_res_feats_1", "image_embed"), source.encoder.run(None, {"image": x})))
    low = source.decoder.run(["masks", "iou_predictions"], {
        **feats, "point_coords": scaled.reshape(1, 2, 2).astype(np.float32), "point_labels": np.array([[2, 3]], np.float32),
        "mask_input": np.zeros((1, 1, SAM_S // 4, SAM_S // 4), np.float32), "has_mask_input": np.zeros(1, np.float32)})
    ref_low = ref.pred_masks[0, 0].numpy()  # [1, S/4, S/4]
    np.testing.assert_allclose(low[0][0], ref_low, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(low[1][0], ref.iou_scores[0, 0].numpy(), rtol=1e-4, atol=1e-5)
    ref_logit = cv2.resize(ref_low[0], (90, 60), interpolation=cv2.INTER_LINEAR)
    sure = np.abs(ref_logit) > 1e-3  # pixels whose sign float noise cannot flip
    np.testing.assert_array_equal(masks[0][sure], (ref_logit > 0)[sure])


def test_dinov3_features_match_transformers(exported):
    dino = exported["models"][2]
    path = exported["out"] / f"dinov3_layer{DINO_LAYER}.onnx"
    rgb = _rgb(60, 100, seed=3)  # another size and aspect than the traced 48 x 64
    feat = Dinov3OnnxFeatures(Dinov3Config(model_path=path, short_side=48, threads=1))
    grid = feat.feature_grid(rgb)
    x = prepare_image(rgb, 48, 16)
    with torch.no_grad():
        hidden = dino(torch.from_numpy(x), output_hidden_states=True).hidden_states[DINO_LAYER][0].numpy()
    gh, gw = x.shape[2] // 16, x.shape[3] // 16
    assert grid.shape == (gh, gw, 32) and (gh, gw) != (3, 4)
    np.testing.assert_allclose(grid, hidden[5:].reshape(gh, gw, 32), rtol=1e-4, atol=1e-4)  # class + 4 registers dropped


def _error_line(capsys, argv) -> str:
    with pytest.raises(SystemExit) as info:
        cli.main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err
    return err


def test_bad_checkpoint_folders_and_output(exported, tmp_path, capsys):
    folders = exported["folders"]
    err = _error_line(capsys, ["--out", str(tmp_path / "o"), "--sam2", str(tmp_path / "nowhere")])
    assert "nowhere" in err and "checkpoint folder not found" in err
    err = _error_line(capsys, ["--out", str(tmp_path / "o"), "--sam2", str(folders["dinov3"])])
    assert "config.json" in err and "'dinov3_vit'" in err and "SAM 2" in err
    err = _error_line(capsys, ["--out", str(tmp_path / "o"), "--dinov3", str(folders["dinov3"]), "--dinov3-layer", "9"])
    assert "--dinov3-layer 9" in err
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    err = _error_line(capsys, ["--out", str(blocker / "sub"), "--dinov3", str(folders["dinov3"]), "--dinov3-layer", "2"])
    assert "not writable" in err and str(blocker / "sub") in err
    err = _error_line(capsys, ["--out", str(tmp_path / "o")])
    assert "--grounding-dino" in err
    err = _error_line(capsys, ["--out", str(tmp_path / "o"), "--grounding-dino", str(folders["gdino"]), "--detector-size", "64", "96"])
    assert "--detector-size 64 96" in err
    # a folder whose weights are missing: transformers' error becomes one line naming the folder
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "config.json").write_text(json.dumps({"model_type": "dinov3_vit"}))
    err = _error_line(capsys, ["--out", str(tmp_path / "o"), "--dinov3", str(broken), "--dinov3-layer", "2"])
    assert str(broken) in err and "cannot load" in err
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_failed_export_leaves_nothing(exported, tmp_path, monkeypatch):
    """An export that dies half-way (here: after writing part of the file) leaves no file behind."""

    def dies(module, args, f, **kwargs):
        with open(f, "wb") as fh:
            fh.write(b"partial")
        raise RuntimeError("killed")

    monkeypatch.setattr(torch.onnx, "export", dies)
    out = tmp_path / "o"
    with pytest.raises(RuntimeError, match="killed"):
        cli.run(cli.parse_args(["--out", str(out), "--dinov3", str(exported["folders"]["dinov3"]), "--dinov3-layer", "2"]))
    assert list(out.iterdir()) == []

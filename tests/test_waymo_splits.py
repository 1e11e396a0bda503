"""The paper's split lists and evaluation settings shipped with the package."""

from __future__ import annotations

import pytest

from idsplat_ns.data.waymo import experiment_settings, load_split
from idsplat_ns.errors import IDSplatError


def test_split_sizes_and_frame_ranges():
    streetgs, notr, pvg = load_split("streetgs"), load_split("notr_dynamic"), load_split("pvg")
    assert (len(streetgs), len(notr), len(pvg)) == (8, 32, 4)
    assert len({s.segment for s in notr}) == 32
    s105 = next(s for s in streetgs if s.sequence_id == "105")
    assert s105.context_name == "1906113358876584689_1359_560_1379_560"
    assert (s105.start_frame, s105.end_frame) == (20, 186)
    assert s105.frame_range() == (20, 187)  # end inclusive in the paper, exclusive for load_segment
    assert s105.frame_range(use_range=False) == (0, None)
    assert [(s.start_frame, s.end_frame) for s in pvg] == [(61, 109), (26, 74), (6, 54), (26, 74)]
    assert pvg[0].segment == "segment-10235335145367115211_5420_000_5440_000"
    assert all((s.start_frame, s.end_frame) == (0, -1) for s in notr)
    assert notr[0].frame_range(max_frames=50) == (0, 50)
    assert notr[-1].sequence_id == "796"


def test_experiment_settings():
    settings = experiment_settings()
    d = settings["desiregs"]
    assert d.split == "notr_dynamic" and d.cameras == ("FRONT", "FRONT_LEFT", "FRONT_RIGHT")
    assert d.image_size == (640, 960) and d.image_scale == 0.5 and d.train_fraction == 0.9 and d.eval_every == 10
    assert d.max_frames == 50
    a = settings["adgs"]
    assert a.split == "streetgs" and a.cameras == ("FRONT",) and a.image_scale == 1.0 and a.eval_every == 4
    assert settings["view_density"].train_fraction == (0.25, 0.5, 0.75, 1.0)
    assert settings["ablation"].use_split_frame_range is False
    assert settings["splatflow"].split == "pvg" and settings["splatflow"].train_fraction == 0.75


def test_unknown_split_and_missing_file(tmp_path):
    with pytest.raises(IDSplatError, match="choose one of"):
        load_split("kitti")
    with pytest.raises(IDSplatError, match="download segment"):
        load_split("pvg")[0].find_file(tmp_path)

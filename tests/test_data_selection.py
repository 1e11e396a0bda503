"""Choosing data from the command line: format recognition, dataparser subcommands of ns-train,
the paper's protocols, and the memory check before a Waymo load."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from idsplat_ns.data.formats import detect_data, v1_context_name
from idsplat_ns.data.protocols import PANDASET_10, PROTOCOL_NAMES, select_protocol
from idsplat_ns.data.waymo.memory import check_fits, estimate_segment_memory, rays_per_frame
from idsplat_ns.data.waymo.splits import load_split
from idsplat_ns.errors import IDSplatError
from idsplat_ns.nerfstudio.model_inputs import split_data

REPO = Path(__file__).resolve().parents[1]
FRAME = REPO.parent / "shared" / "data" / "waymo" / "pvps_data_one_frame.tfrecord"
NOTR_CONTEXT = load_split("notr_dynamic")[0].context_name
needs_frame = pytest.mark.skipif(not FRAME.is_file(), reason=f"real Waymo frame not found at {FRAME}")


@pytest.fixture(scope="module")
def segments(tmp_path_factory):
    """A 4-frame v1 segment with lidar in a folder beside another one, named as Waymo names them,
    and the same data as a v2 root."""
    if not FRAME.is_file():
        pytest.skip("real Waymo frame not present")
    from idsplat_ns.data.waymo.fixtures import write_synthetic_segment, write_v2_from_v1

    tmp = tmp_path_factory.mktemp("segments")
    folder = tmp / "v1"
    folder.mkdir()
    seg = write_synthetic_segment(FRAME, folder / f"segment-{NOTR_CONTEXT}_with_camera_labels.tfrecord", 4,
                                  top_width=200, side_shape=(20, 60), speed=8.0)
    shutil.copy(FRAME, folder / "segment-other_context_with_camera_labels.tfrecord")
    context = write_v2_from_v1(seg, tmp / "v2")
    return seg, folder, tmp / "v2", context


# --- format recognition ---------------------------------------------------------------------

def test_v1_context_name_from_waymo_file_names():
    assert v1_context_name(Path(f"segment-{NOTR_CONTEXT}_with_camera_labels.tfrecord")) == NOTR_CONTEXT
    assert v1_context_name(Path("segment-abc.tfrecord")) == "abc"
    assert v1_context_name(Path("frame.tfrecord")) is None


def test_detect_each_format(tiny_street, segments):
    seg, folder, v2, context = segments
    assert detect_data(tiny_street).format == "pandaset"
    found = detect_data(seg)
    assert (found.format, found.context_name) == ("waymo-v1", NOTR_CONTEXT)
    assert detect_data(folder, segment=NOTR_CONTEXT).path == seg
    assert detect_data(folder, segment=seg.name).path == seg
    found = detect_data(v2)
    assert (found.format, found.context_name) == ("waymo-v2", context)  # one context: no need to name it
    assert detect_data(v2 / "training", context_name=context).format == "waymo-v2"


@pytest.mark.parametrize("case, match", [
    ("missing", "no such file or folder"),
    ("not_tfrecord", "not a .tfrecord"),
    ("empty_dir", "not a recognised sequence"),
    ("two_segments", "choose one with --segment"),
    ("unknown_segment", "no segment 'nope'"),
    ("unknown_context", "is not in this v2 root"),
])
def test_detect_bad_paths_name_the_path_and_the_option(tmp_path, segments, case, match):
    _, folder, v2, _ = segments
    (tmp_path / "x.txt").write_text("x")
    (tmp_path / "empty").mkdir()
    path, kwargs = {
        "missing": (tmp_path / "nope", {}), "not_tfrecord": (tmp_path / "x.txt", {}), "empty_dir": (tmp_path / "empty", {}),
        "two_segments": (folder, {}), "unknown_segment": (folder, {"segment": "nope"}),
        "unknown_context": (v2, {"context_name": "nope"}),
    }[case]
    with pytest.raises(IDSplatError, match=match) as err:
        detect_data(path, **kwargs)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


# --- protocols --------------------------------------------------------------------------------

def test_protocols_follow_the_papers_settings():
    spec = load_split("streetgs")[0]
    sel = select_protocol("streetgs", spec.segment)
    assert sel.cameras == ("FRONT",) and sel.downscale_factor == 1.0 and sel.eval_every == 4
    assert (sel.start_frame, sel.end_frame) == (spec.start_frame, spec.end_frame + 1)  # inclusive in the paper
    sel = select_protocol("notr-dynamic", NOTR_CONTEXT)
    assert sel.cameras == ("FRONT", "FRONT_LEFT", "FRONT_RIGHT") and sel.downscale_factor == 2.0
    assert (sel.start_frame, sel.end_frame, sel.eval_every) == (0, 50, 10)
    sel = select_protocol("view-density-25", NOTR_CONTEXT)
    assert sel.cameras == ("FRONT",) and sel.train_fraction == 0.25 and sel.eval_every is None and sel.end_frame == 50
    sel = select_protocol("pandaset-10", "028")
    assert sel.cameras is None and sel.train_fraction == 0.5 and sel.downscale_factor == 1.0
    assert len(PANDASET_10) == 10 and len(PROTOCOL_NAMES) == 8


@pytest.mark.parametrize("name, sequence, match", [
    ("streetgs", NOTR_CONTEXT, "is not in its split"),
    ("pandaset-10", "002", "not one of its ten"),
    ("kitti", "001", "unknown; choose one of"),
])
def test_protocol_errors(name, sequence, match):
    with pytest.raises(IDSplatError, match=match):
        select_protocol(name, sequence)


# --- memory -----------------------------------------------------------------------------------

def test_rays_per_frame_closed_form():
    assert rays_per_frame(["TOP"], second_return=False) == 64 * 2650
    assert rays_per_frame(["TOP", "REAR"], second_return=False) == 64 * 2650 + 200 * 600
    assert rays_per_frame(["TOP"], second_return=True) > 64 * 2650


def test_memory_estimate_counts_frames_and_refuses_what_does_not_fit(segments):
    seg, _, v2, context = segments
    full = estimate_segment_memory(seg, None, None, True)
    assert full.frames == 4 and full.lidars == ("TOP", "FRONT", "SIDE_LEFT", "SIDE_RIGHT", "REAR")
    part = estimate_segment_memory(seg, None, ["top"], False, start=1, end=3)
    assert part.frames == 2 and part.bytes < full.bytes / 2
    assert estimate_segment_memory(v2, context, [], True, start=1).frames == 3
    check_fits(full, 10 * full.bytes, "seg")  # fits: nothing raised
    with pytest.raises(IDSplatError, match=r"--lidars TOP.*--end-frame|--end-frame.*--lidars TOP"):
        check_fits(full, full.bytes // 2, "seg")
    with pytest.raises(IDSplatError, match="--lidars LIDAR9: not a Waymo lidar"):
        estimate_segment_memory(seg, None, ["LIDAR9"], True)
    # The lidars named and counted are those the file holds, not all five: the v2 copy holds the
    # same five; the real frame (a panoptic-label frame) holds none.
    assert estimate_segment_memory(v2, context, None, True).lidars == full.lidars
    bare = estimate_segment_memory(FRAME, None, None, True)
    assert bare.lidars == () and bare.describe().startswith("1 frames, no lidar")


# --- dataparsers as ns-train subcommands ---------------------------------------------------------

def _parse(argv: list[str]):
    """What ns-train builds from its arguments (nerfstudio's own tyro union of methods)."""
    pytest.importorskip("nerfstudio")
    import tyro
    from nerfstudio.configs.method_configs import AnnotatedBaseConfigUnion

    return tyro.cli(AnnotatedBaseConfigUnion, args=argv)


def test_ns_train_dataparser_subcommands():
    from idsplat_ns.nerfstudio.dataparser import (
        AutoDataParserConfig,
        BuiltinDataParserConfig,
        WaymoDataParserConfig,
    )

    cfg = _parse(["idsplat-fast"])
    assert isinstance(cfg.pipeline.datamanager.dataparser, AutoDataParserConfig)
    cfg = _parse(["idsplat-fast", "idsplat-builtin", "--preset", "tiny", "--seed", "3"])
    parser = cfg.pipeline.datamanager.dataparser
    assert isinstance(parser, BuiltinDataParserConfig) and (parser.preset, parser.seed) == ("tiny", 3)
    cfg = _parse(["idsplat", "idsplat-waymo", "--data", "x.tfrecord", "--lidars", "TOP", "--second-return", "False",
                  "--protocol", "streetgs"])
    parser = cfg.pipeline.datamanager.dataparser
    assert isinstance(parser, WaymoDataParserConfig)
    assert (parser.lidars, parser.second_return, parser.protocol) == (("TOP",), False, "streetgs")


@needs_frame
def test_auto_dataparser_recognises_waymo_and_applies_a_protocol(segments, capsys):
    pytest.importorskip("nerfstudio")
    from idsplat_ns.nerfstudio.dataparser import AutoDataParserConfig, WaymoDataParserConfig

    seg, folder, _, _ = segments
    config = AutoDataParserConfig(data=folder, segment=NOTR_CONTEXT, protocol="notr-dynamic")
    concrete = config.concrete()
    assert isinstance(concrete, WaymoDataParserConfig) and concrete.data == seg
    assert (concrete.train_fraction, concrete.eval_every) == (0.75, 4)  # Waymo's default split unless given
    assert "a Waymo v1 segment" in capsys.readouterr().out
    parser = config.setup()
    train, test = parser.get_dataparser_outputs("train"), parser.get_dataparser_outputs("test")
    # notr-dynamic: three front cameras at half resolution, every 10th frame held out.
    assert {im.camera for im in split_data(train.metadata).images} == {"FRONT", "FRONT_LEFT", "FRONT_RIGHT"}
    assert sorted({im.frame_index for im in split_data(test.metadata).images}) == [0]
    assert sorted({im.frame_index for im in split_data(train.metadata).images}) == [1, 2, 3]
    assert int(train.cameras.width[0]) == 960 and split_data(train.metadata).protocol == "notr-dynamic"
    assert split_data(train.metadata).scene.has_lidar


@needs_frame
def test_waymo_protocol_on_a_segment_it_does_not_list(segments):
    pytest.importorskip("nerfstudio")
    from idsplat_ns.nerfstudio.dataparser import AutoDataParserConfig

    _, _, v2, _ = segments
    with pytest.raises(IDSplatError, match="is not in its split"):
        AutoDataParserConfig(data=v2, protocol="pvg").setup().get_dataparser_outputs("train")
    from idsplat_ns.nerfstudio.dataparser import PandaSetDataParserConfig

    with pytest.raises(IDSplatError, match="is a waymo protocol, but the data is pandaset"):
        PandaSetDataParserConfig(data=Path("/data/pandaset/001"), protocol="pvg").resolved()


@needs_frame
def test_waymo_lidar_selection_reaches_the_loader(segments):
    pytest.importorskip("nerfstudio")
    from idsplat_ns.nerfstudio.dataparser import WaymoDataParserConfig

    seg, _, _, _ = segments
    config = WaymoDataParserConfig(data=seg, lidars=("TOP",), second_return=False, cameras=("FRONT",), end_frame=2)
    scene = config.setup().scene
    ids = np.unique(np.concatenate([s.sensor_ids for s in scene.lidar]))
    assert ids.tolist() == [1]  # TOP only
    with pytest.raises(IDSplatError, match="--lidars REAR2: not a Waymo lidar"):
        WaymoDataParserConfig(data=seg, lidars=("REAR2",), end_frame=1).setup().scene  # noqa: B018


@needs_frame
def test_auto_dataparser_takes_each_formats_lidar_options(segments, tiny_street):
    # `ns-train idsplat --data X` and idsplat-preprocess (which builds this config) take the lidar
    # options that the memory check names, without the idsplat-waymo subcommand.
    pytest.importorskip("nerfstudio")
    from idsplat_ns.nerfstudio.dataparser import AutoDataParserConfig, PandaSetDataParserConfig

    seg, _, v2, _ = segments
    for data in (seg, v2):
        concrete = AutoDataParserConfig(data=data, lidars=("TOP",), second_return=False).concrete()
        assert (concrete.lidars, concrete.second_return) == (("TOP",), False)
    scene = AutoDataParserConfig(data=seg, lidars=("TOP",), cameras=("FRONT",), end_frame=2).load_scene()
    assert np.unique(np.concatenate([s.sensor_ids for s in scene.lidar])).tolist() == [1]  # TOP only
    concrete = AutoDataParserConfig(data=tiny_street, lidar_sensors=(0, 1)).concrete()
    assert isinstance(concrete, PandaSetDataParserConfig) and concrete.lidar_sensors == (0, 1)
    cases = [(dict(data=tiny_street, lidars=("TOP",)), "--lidars: not an option for .*PandaSet layout.*--lidar-sensors"),
             (dict(data=tiny_street, second_return=False), "--second-return: not an option for"),
             (dict(data=seg, lidar_sensors=(1,)), "--lidar-sensors: not an option for .*Waymo.*--lidars"),
             (dict(lidars=("TOP",), second_return=False), "--lidars and --second-return: not an option for the built-in")]
    for kwargs, match in cases:
        with pytest.raises(IDSplatError, match=match) as err:
            AutoDataParserConfig(**kwargs).concrete()
        assert "\n" not in str(err.value)


def test_auto_without_data_is_the_builtin_street():
    pytest.importorskip("nerfstudio")
    from idsplat_ns.nerfstudio.dataparser import AutoDataParserConfig, BuiltinDataParserConfig

    concrete = AutoDataParserConfig(builtin_preset="tiny", builtin_seed=2, train_fraction=0.8).concrete()
    assert isinstance(concrete, BuiltinDataParserConfig) and (concrete.preset, concrete.seed) == ("tiny", 2)
    assert (concrete.train_fraction, concrete.eval_every) == (0.8, None)


# --- bad real-data input: one line naming the file or option ------------------------------------

MOTION = FRAME.parent / "motion_data_one_scenario.tfrecord"


@needs_frame
def test_bad_waymo_input(segments, tmp_path):
    pytest.importorskip("nerfstudio")
    from idsplat_ns.data.waymo import load_segment
    from idsplat_ns.nerfstudio.dataparser import WaymoDataParserConfig

    seg, _, v2, context = segments
    cases = []
    if MOTION.is_file():  # a TFRecord of another kind of proto (Waymo Motion's Scenario)
        cases.append((lambda: load_segment(MOTION), "not a Waymo Frame protobuf", str(MOTION)))
    broken = tmp_path / "v2"
    shutil.copytree(v2, broken)
    shutil.rmtree(broken / "training" / "camera_image")
    cases += [
        (lambda: load_segment(broken, context_name=context), "missing v2 component camera_image", "camera_image"),
        (lambda: WaymoDataParserConfig(data=seg, cameras=("REAR_CAMERA",), end_frame=1).setup().scene,
         "no camera named REAR_CAMERA", str(seg)),
    ]
    for call, match, named in cases:
        with pytest.raises(IDSplatError, match=match) as err:
            call()
        assert named in str(err.value) and "\n" not in str(err.value)


def test_an_instance_mode_without_lidar_is_refused(tiny_street):
    from idsplat_ns.data.pandaset import load_sequence
    from idsplat_ns.instances.modes import instance_tracks_for_mode
    from idsplat_ns.instances.runner import PreprocessConfig

    scene = load_sequence(tiny_street, load_lidar=False)
    for mode in ("self-supervised", "oracle"):
        with pytest.raises(IDSplatError, match="instance-mode static") as err:
            instance_tracks_for_mode(scene, mode, set(scene.frame_indices.tolist()), PreprocessConfig(), Path("/nonexistent"))
        assert str(tiny_street) in str(err.value)
    assert instance_tracks_for_mode(scene, "static", set(), PreprocessConfig(), Path("/nonexistent")) is None

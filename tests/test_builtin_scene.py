"""The built-in street is made once, reused, and remade when its generator record changes; a run on
it gives the viewer the street's folder."""

import json

from idsplat_ns.nerfstudio.builtin_scene import builtin_street


def test_builtin_street_is_cached_and_refreshed(tmp_path, monkeypatch):
    monkeypatch.setenv("IDSPLAT_CACHE", str(tmp_path))
    first = builtin_street("tiny", seed=3)
    assert first.parent == tmp_path / "synthetic" and (first / "lidar" / "00.pkl.gz").is_file()
    stamp = (first / "lidar" / "00.pkl.gz").stat().st_mtime_ns
    assert builtin_street("tiny", seed=3) == first
    assert (first / "lidar" / "00.pkl.gz").stat().st_mtime_ns == stamp  # reused, not rewritten
    record = first / "idsplat_extras" / "generator.json"
    data = json.loads(record.read_text())
    data["version"] = "an older generator"
    record.write_text(json.dumps(data))
    assert builtin_street("tiny", seed=3) == first
    assert json.loads(record.read_text())["version"] != "an older generator"  # remade by this generator
    assert not list((tmp_path / "synthetic").glob(".*tmp*"))  # no temporary folder left behind


def test_a_builtin_street_run_gives_the_viewer_its_folder(tmp_path, monkeypatch):
    # ns-viewer opens the datamanager's data path; `make demo`'s run (built-in street, no --data)
    # has none in its config: the street's cache folder stands in for it.
    from method_configs.idsplat import make_trainer_config

    monkeypatch.setenv("IDSPLAT_CACHE", str(tmp_path / "cache"))
    cfg = make_trainer_config("idsplat-fast", 10, (10**6, 10**6), fast=True)
    cfg.pipeline.datamanager.dataparser.builtin_preset = "tiny"
    cfg.pipeline.datamanager.instance_mode = "static"
    assert cfg.pipeline.datamanager.dataparser.data is None
    manager = cfg.pipeline.datamanager.setup(device="cpu", test_mode="test", world_size=1, local_rank=0)
    path = manager.get_datapath()
    assert path.is_dir() and path.parent == tmp_path / "cache" / "synthetic" and (path / "lidar").is_dir()

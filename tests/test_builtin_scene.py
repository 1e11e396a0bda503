"""The built-in street is made once, reused, and remade when its generator record changes."""

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

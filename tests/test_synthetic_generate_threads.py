"""Two threads of one process writing the same built-in street at once (``bench_modes --jobs 2``,
the datamanager and a bench in one process) each get a whole street."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

from idsplat_ns.data.synthetic.generate import generate_sequence
from idsplat_ns.data.synthetic.config import camera_names, get_preset


def test_two_threads_writing_the_same_street_both_get_it_whole(tmp_path):
    def write(_):
        return generate_sequence(tmp_path, preset="tiny", seed=3, overwrite=True, workers=1, progress=False)

    with ThreadPoolExecutor(2) as pool:
        paths = list(pool.map(write, range(2)))
    assert paths[0] == paths[1] and (paths[0] / "idsplat_extras" / "generator.json").is_file()
    assert len(list((paths[0] / "camera").iterdir())) == len(camera_names(get_preset("tiny").cameras))
    assert not [p for p in tmp_path.iterdir() if ".tmp-" in p.name]  # nothing half-written is left

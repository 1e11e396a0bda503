"""The CPU-machine guards: torchvision imports and its NMS works; the start-up hook file is written."""

import torch


def test_torchvision_imports_and_nms_is_correct():
    import torchvision  # noqa: F401 - the import itself is what the guard makes possible

    from idsplat_ns._compat.torchvision_ops import _nms_reference

    boxes = torch.tensor([[0, 0, 10, 10], [1, 1, 11, 11], [50, 50, 60, 60], [0, 0, 10, 9.0]])
    scores = torch.tensor([0.9, 0.8, 0.7, 0.95])
    # Box 3 scores highest; IoU(3, 0) = 90/100 and IoU(3, 1) = 72/118 both exceed 0.5, box 2 is apart.
    expected = [3, 2]
    assert _nms_reference(boxes, scores, 0.5).tolist() == expected
    # Whichever implementation is registered (the compiled one, or the guard's), it agrees.
    assert torch.ops.torchvision.nms(boxes, scores, 0.5).tolist() == expected


def test_startup_hook_file(tmp_path):
    from idsplat_ns._compat.startup import PTH_NAME, write_pth

    path = write_pth(str(tmp_path))
    assert path == str(tmp_path / PTH_NAME)
    assert (tmp_path / PTH_NAME).read_text().startswith("import idsplat_ns._compat.startup")
    assert [p.name for p in tmp_path.iterdir()] == [PTH_NAME]  # nothing temporary left behind


def test_the_start_up_hook_leaves_the_package_to_the_program_s_own_path(tmp_path):
    """With the hook installed (make install), a Python started in another tree imports that tree's
    idsplat_ns (the side-by-side benches run engines so), and the guard finder is in place."""
    import subprocess
    import sys
    import sysconfig
    from pathlib import Path

    import pytest

    from idsplat_ns._compat.startup import PTH_NAME

    if not (Path(sysconfig.get_paths()["purelib"]) / PTH_NAME).exists():
        pytest.skip("the start-up hook is not installed in this environment (idsplat-install-compat)")
    (tmp_path / "idsplat_ns").mkdir()
    (tmp_path / "idsplat_ns" / "__init__.py").write_text('__version__ = "another tree"\n')
    code = ("import sys; finder = any(type(f).__name__ == '_GuardFinder' for f in sys.meta_path); "
            "before = sorted(n for n in sys.modules if n.startswith('idsplat_ns')); "
            "import idsplat_ns; print(finder, before, idsplat_ns.__version__)")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "True [] another tree"


def test_the_guard_finder_steps_aside_for_another_revisions_copy(monkeypatch):
    """Another revision's code installs its own copy of the finder (its install() tells them apart by
    class): only one may guard, or torchvision's operators would be defined twice."""
    import sys

    import idsplat_ns._compat.torchvision_ops  # noqa: F401 - imported before meta_path is narrowed
    from idsplat_ns._compat import startup

    class _GuardFinder:  # the other copy: the same name, another class
        def find_spec(self, fullname, path=None, target=None):
            return None

    mine = startup._GuardFinder()
    monkeypatch.setattr(sys, "meta_path", [_GuardFinder(), mine])
    assert mine.find_spec("torchvision") is None and "torchvision" not in mine._done
    monkeypatch.setattr(sys, "meta_path", [mine])
    assert mine.find_spec("torchvision") is None and "torchvision" in mine._done  # alone, it guards


def test_nerfstudio_external_method_placeholders_skip_the_stack_walk(capsys):
    import pytest

    pytest.importorskip("nerfstudio")
    from nerfstudio.configs import external_methods as em

    # The start-up hook patched the class as the module was loaded (no inspect.stack() per placeholder).
    assert getattr(em.ExternalMethodDummyTrainerConfig.__post_init__, "_idsplat_fast", False)
    configs, descriptions = em.get_external_methods()
    assert configs and set(configs) == set(descriptions)
    assert capsys.readouterr().out == ""  # built quietly, as nerfstudio builds them
    # Picked by the user (built anywhere else), a placeholder still says how to install the method.
    method = em.ExternalMethod("INSTALL-INSTRUCTIONS", configurations=[("some-method", "d")], pip_package=None)
    with pytest.raises(SystemExit) as stop:
        em.ExternalMethodDummyTrainerConfig(method_name="some-method", method=method)
    assert stop.value.code == 0
    assert "INSTALL-INSTRUCTIONS" in capsys.readouterr().out


def test_nerfstudio_patch_leaves_an_unknown_layout_alone():
    from types import SimpleNamespace

    from idsplat_ns._compat.nerfstudio_startup import speed_up_external_methods

    speed_up_external_methods(SimpleNamespace())  # no such class: nothing to do, no error

    class Placeholder:
        def __post_init__(self):
            return "original"

    module = SimpleNamespace(ExternalMethodDummyTrainerConfig=Placeholder)
    speed_up_external_methods(module)
    patched = Placeholder.__post_init__
    speed_up_external_methods(module)  # twice: wrapped once
    assert Placeholder.__post_init__ is patched

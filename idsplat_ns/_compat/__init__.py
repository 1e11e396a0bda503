"""Guards for two CPU-machine snags, each doing nothing where the real thing works, and one fix
to nerfstudio's start-up time.

* torchvision from PyPI ships compiled ops linked against CUDA; with a CPU-only torch they fail to
  load and ``import torchvision`` then dies registering a fake kernel for ``torchvision::nms``.
  nerfstudio imports torchvision at start-up, so ``ns-train`` would not start. See
  :mod:`idsplat_ns._compat.torchvision_ops`.
* open3d's wheel needs ``libusb-1.0.so.0``, which minimal machines lack; the ``libusb-package``
  wheel ships one. See :mod:`idsplat_ns._compat.libusb`.
* nerfstudio walks the stack with ``inspect.stack()`` for each of its 26 external-method
  placeholders at every start (3-5 s of each ``ns-train``); see
  :mod:`idsplat_ns._compat.nerfstudio_startup`.

All three are applied by an import hook (:mod:`idsplat_ns._compat.startup`) that a ``.pth`` file
installs at interpreter start, so they run before nerfstudio's first import of torchvision (and
the third just after nerfstudio loads its external-method list).

Layer: the lowest beside ``errors`` and ``atomic``, which are all it may import of the project
(its start-up hook runs at every Python start and must stay cheap).
"""

"""The project's command lines other than ns-train/ns-eval: ``idsplat-preprocess``,
``idsplat-edit``, ``idsplat-export``, ``idsplat-render-drive``, ``idsplat-report``, and the
translators that turn a failure inside nerfstudio's own commands into one line.

Layer: the top of the package beside ``batch``. It may import everything below it, the nerfstudio
adapter included; nothing in ``idsplat_ns`` imports it, and it never imports ``method_configs``.
"""

"""The nerfstudio adapter: dataparser, dataset, datamanager, model, pipeline, trainer and its
config, schedulers, and the viewer's panel and scene layers.

Layer: above ``runs``, below the command lines and ``batch``. It may import everything under it;
never ``cli``, ``batch`` or ``method_configs``.
"""

"""``idsplat-batch``: many sequences through preprocessing, training and evaluation as Ray tasks.

Modules: ``sequences`` (the list to run), ``commands`` (each step's command line), ``layout``
(the output folder), ``plan`` (what is left per sequence: resumability), ``tasks`` (the Ray task
that runs a step in a subprocess), ``runner`` (the Ray driver and state lines), ``aggregate``
(the results table and plot), ``cli`` (the command). Reference: docs/batch.md.

Layer: the top of the package beside ``cli``; it may import everything below (it builds its
command lines from ``instances.options`` and reads checkpoints through ``runs``), never ``cli``
or ``method_configs``.
"""

"""Instance decomposition without annotations: masks, lifting to lidar, features, registration
(the track builder and its passes), static conversion, smoothing.

Layer: above ``data`` and ``render``, below ``model``; it may import those and the lowest layer.
"""

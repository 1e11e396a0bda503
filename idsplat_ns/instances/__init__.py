"""Instance decomposition without annotations: masks, lifting to lidar, features, registration, smoothing."""

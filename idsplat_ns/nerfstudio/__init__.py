"""The only layer that imports nerfstudio: dataparsers, datamanager, model, pipeline."""

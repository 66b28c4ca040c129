"""MERLION Companion: the vision side (frames, encoders, enhancers, sampler, pipeline, storage) and the processes."""

__version__ = "0.1.0"

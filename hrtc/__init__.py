"""hrtc: Hierarchical Reinforcement Thompson Composition."""

__version__ = "0.1.0"

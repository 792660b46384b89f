"""sgreg_core: SG-Reg scene-graph registration as a pure library (numpy + torch, no ROS)."""

__version__ = "0.1.0"

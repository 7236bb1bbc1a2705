"""robobpp: closed-loop benchmark and evaluation service for robotic online 3D bin packing."""

__version__ = "0.1.0"

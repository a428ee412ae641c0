"""The virtual robot: plant physics, effects, drive emulation (and, later, protocol servers)."""

__version__ = "0.1.0"

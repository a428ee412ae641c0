"""Host side of the bench: loop runner, experiments, identification, control, reports (`hil`)."""

__version__ = "0.1.0"

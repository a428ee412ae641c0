"""Plots of recordings, shared by the host (``hil run``) and the virtual robot (``virtual-robot
simulate``), and the figure margins the commands' plots share (:mod:`plots.layout`):
matplotlib, loaded only when a plot is drawn.

Imports: :mod:`drivers` (the :class:`drivers.recording.Recording` it draws). Above drivers and
profiles, below ``virtual_robot`` and ``hil``, which may both import it (tests/test_layout.py);
``drivers/`` itself draws nothing.
"""

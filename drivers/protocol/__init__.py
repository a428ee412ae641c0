"""Drive protocol codecs shared by the host drivers and the virtual robot's servers.

Pure functions and data: no buses, no ports, no clocks. ``cia402`` is the CAN side (CiA 301
framing + CiA 402 objects); ``gemini`` is the serial ASCII dialect; ``mit`` the MIT mode of
T-Motor/CubeMars AK actuators (Mini Cheetah protocol);
``odrive`` ODrive's CANSimple; ``moteus`` the mjbots moteus register protocol and the
fdcanusb's line protocol.
"""

"""Unitree's low-level DDS interface (``rt/lowcmd`` / ``rt/lowstate``, ``unitree_hg`` types): the
messages' layouts and CRC, the transport, the DDS plan and the Robot that drives a G1 through it.

Only :mod:`giwbc.hal.dds.transport` and :mod:`giwbc.hal.dds.idl` need ``cyclonedds`` (the ``dds``
extra); the layouts, the CRC, the messages and the plan do not.
"""

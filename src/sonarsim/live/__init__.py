"""Live ROS 2 output over DDS, without ROS installed (issue 40).

:mod:`sonarsim.live.dds` maps ROS 2 topics and message types onto DDS (``DESIGN.md`` section
14) and turns the messages sonarsim's bags hold into DDS samples whose payload is the same CDR.
It needs the ``live`` extra (Cyclone DDS's Python binding and ``rosbags``); importing this
package works without it.
"""

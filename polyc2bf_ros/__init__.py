"""PolyC2BF safety filter for ROS 2: a numpy core plus a thin rclpy shell.

``core/`` is the filter without ROS (it imports nothing of the shell).  The shell here turns
messages into the core's arrays and back: ``ports/`` (one per input), ``obstacle_intake``
(the worker process running ``obstacle_pipeline``), ``lockstep_gate``, ``reporter``, the
nodes (``safety_filter_node``, ``safety_filter_lifecycle``) and their parameters
(``filter_parameters``, ``node_parameters``).  Nothing here imports ``sim_bridge``.
"""

"""The safety filter node's inputs: one port per source, each owning its subscription.

``odometry_port`` (``odom``), ``command_port`` (``cmd_vel_in`` / ``wrench_in``),
``marker_port`` (``obstacles``), ``scan_port`` (``scan_topics``), ``transform_port``
(``/tf_static``) and ``footprint_port`` (``footprint_topic``, which sets the
``filter.footprint`` parameter).  A port subscribes through the node (serialized but the
footprint's, destroyed when the node releases its configuration), reads what the control
path needs and feeds its watchdog;
obstacle sources hand their bytes to the obstacle worker (``obstacle_intake``), whose
snapshots ``obstacle_feed`` hands to the decision.  Messages that cannot be used are counted
and logged by ``invalid_messages``.  Ports import the core and the shell's message
readers (``conversions``, ``obstacle_intake``), never the node.
"""

"""What every sdhn package shares: YAML and bounded JSON loading, dotted overrides, drop
counters, diagnostics levels, litter cleanup, waiting on a condition, and the ROS plumbing
(``sdhn_base.ros``: QoS profiles, topic names, CDR, the node runner, parameters, status files).

The bottom floor: it imports no other sdhn package except the message interfaces."""

"""ROS plumbing shared by every sdhn node: the node runner, the QoS profiles, the topic names."""

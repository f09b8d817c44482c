"""Simulation side of sdhn: environments (MAIF, RWARE), the lock-step simulator and its node, the
ROS plumbing every node shares, recording and replay, the Foxglove view, and the launcher."""

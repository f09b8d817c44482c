"""Simulation side of sdhn: environments (MAIF, RWARE), the simulator node, recording and replay."""

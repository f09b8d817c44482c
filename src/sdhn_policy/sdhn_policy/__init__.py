"""Decentralised execution: the actor network's NumPy runtime, weight files, and the actor node."""

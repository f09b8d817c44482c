"""The Foxglove view of a team: world, drawing, the stateful renderer, its channels, the node."""

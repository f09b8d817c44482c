"""Starting a whole sdhn graph from one YAML file (supervisor) and plotting its episodes."""

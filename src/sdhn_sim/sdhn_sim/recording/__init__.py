"""MCAP recordings: the writer, its schemas, the recorder node, the reader and replay."""

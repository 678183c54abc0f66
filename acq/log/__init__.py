"""MCAP logs: the message schemas, the recorder's writer, reading, summaries and repair."""

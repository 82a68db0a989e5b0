"""Traces ashore: the trace CSV format, the files a command reads, replay checks."""

"""What a run leaves behind: the summary, the plots, latency figures from the event log, the
controllers' hi-res record with its ATSPM measures and charts, JSON every reader can load, and
files written whole."""

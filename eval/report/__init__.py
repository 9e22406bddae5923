"""What a person reads: the self-contained HTML page of a run or a sweep, a Rerun
recording, a frame preview and the strategies table."""

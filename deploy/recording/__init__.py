"""Recording: the system's traffic to MCAP and back (record, read, info), the replay of a
recording into one service, and the figures of a recorded run."""

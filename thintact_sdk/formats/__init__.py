"""File formats the SDK reads and writes: profiles, recordings, raw frames, MCAP logs, bundle archives, and the strict readers of untrusted files."""

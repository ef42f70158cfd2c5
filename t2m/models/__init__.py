"""The networks of T2M; each is built from its config alone and knows nothing of files."""

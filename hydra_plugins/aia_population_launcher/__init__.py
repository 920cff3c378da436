"""``hydra/launcher=population``: the jobs of a sweep that can share a program train as one population."""

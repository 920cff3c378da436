"""Where a run keeps its checkpoints in its folder, importable without torch (so that the apps name them in their
refusals and reports, and the launcher finds them, before training loads)."""

CHECKPOINT_NAME = "checkpoints/last.pt"
PREVIOUS_CHECKPOINT_NAME = "checkpoints/previous.pt"  # the one before: what resume=auto falls back to

"""Training: data streams, losses, the resumable loop and weight surgery (not imported by the running pipeline)."""

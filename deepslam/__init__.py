"""The `deepslam` command: a thin wiring of frontend, backend, sim and logs."""
